//! The files a scene names: meshes (OBJ, PLY) and OpenVDB grids, read and
//! checked while the scene is, errors located at the field that names them.

use super::locate::{Checker, Seg};
use super::raw::{RawExtinction, RawGridMap, RawIndex, RawObject, RawProfile, RawShape};
use super::MAX_EXTINCTION;
use crate::error::Result;
use crate::mesh_solid::MeshSolid;
use crate::object::{GridExtinction, GridIndex, IndexProfile, Material};
use crate::shape::Shape;
use crate::vdb::{FloatVolume, VdbError};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The mesh file `file` (OBJ or PLY, relative to the scene file), an
/// error located at `at`.
pub(super) fn load_mesh(c: &Checker, at: &[Seg], file: &str) -> Result<eikon_mesh::Mesh> {
    let base = Path::new(c.origin).parent().unwrap_or(Path::new(""));
    eikon_mesh::load(base.join(file)).map_err(|e| c.err(at, e.to_string()))
}

/// A mesh shape, once its mesh is known to bound a solid: closed, manifold,
/// consistently oriented, outward (a mesh wound inside out is flipped). A
/// file that repeats vertices along seams (exporters do, for per-corner
/// normals or texture coordinates) is welded at bit-identical positions
/// first; its normals are kept.
pub(super) fn mesh_shape(
    c: &Checker,
    at: &[Seg],
    mut mesh: eikon_mesh::Mesh,
    smooth: bool,
) -> Result<Shape> {
    if mesh.require_closed().is_err() {
        let mut welded = mesh.clone();
        if welded.weld(0.0).is_ok() && welded.require_closed().is_ok() {
            mesh = welded;
        }
    }
    let report = mesh
        .require_closed()
        .map_err(|e| c.err(at, e.to_string()))?;
    if report.signed_volume < 0.0 {
        mesh.flip();
    }
    Ok(Shape::Mesh(Arc::new(MeshSolid::new(
        Arc::new(mesh),
        smooth,
    ))))
}

/// VDB float grids read while checking a scene, shared by the fields that
/// name the same file and grid.
#[derive(Default)]
pub(super) struct Volumes(HashMap<(PathBuf, String), Arc<FloatVolume>>);

impl Volumes {
    /// Grid `grid` of `file` (relative to the scene file); errors are
    /// located at `at.file` or `at.grid`.
    pub(super) fn load(
        &mut self,
        c: &Checker,
        at: &[Seg],
        file: &str,
        grid: &str,
    ) -> Result<Arc<FloatVolume>> {
        let base = Path::new(c.origin).parent().unwrap_or(Path::new(""));
        let path = base.join(file);
        let key = (path.clone(), grid.to_string());
        if let Some(v) = self.0.get(&key) {
            return Ok(v.clone());
        }
        let v = crate::vdb::read_float_grid(&path, grid).map_err(|e| {
            let field = match e {
                VdbError::NoSuchGrid { .. } | VdbError::WrongType { .. } => "grid",
                _ => "file",
            };
            c.err(&[at, &[Seg::Key(field)]].concat(), e.to_string())
        })?;
        if !v.is_finite() {
            return Err(c.err(
                &[at, &[Seg::Key("grid")]].concat(),
                format!(
                    "{}: grid `{grid}` holds NaN or infinite values",
                    path.display()
                ),
            ));
        }
        let v = Arc::new(v);
        self.0.insert(key, v.clone());
        Ok(v)
    }
}

/// Index and extinction of object `i` from VDB grids, where the file asks
/// for them (`index = { type = "vdb", ... }`, `extinction = { type = "vdb",
/// ... }`). `file` and `grid` default to those of a VDB shape.
pub(super) fn attach_grids(
    c: &Checker,
    volumes: &mut Volumes,
    i: usize,
    o: &RawObject,
    m: &mut Material,
) -> Result<()> {
    use Seg::{Index as I, Key as K};
    let from_shape = match &o.shape {
        RawShape::Vdb { file, grid, .. } => Some((file, grid)),
        _ => None,
    };
    let source =
        |at: &[Seg], file: &Option<String>, grid: &Option<String>| -> Result<(String, String)> {
            let pick = |own: &Option<String>, shape: Option<&String>, key: &'static str| {
                own.clone().or_else(|| shape.cloned()).ok_or_else(|| {
                    c.err(
                        at,
                        format!("`{key}` is required (or a shape of type \"vdb\" to take it from)"),
                    )
                })
            };
            Ok((
                pick(file, from_shape.map(|s| s.0), "file")?,
                pick(grid, from_shape.map(|s| s.1), "grid")?,
            ))
        };
    if let RawIndex::Profile(RawProfile::Vdb { file, grid, scale }) = &o.index {
        let at = [K("object"), I(i), K("index")];
        let (file, grid) = source(&at, file, grid)?;
        let volume = volumes.load(c, &at, &file, &grid)?;
        if let Some(k) = scale {
            c.finite(&[&at[..], &[K("scale")]].concat(), &[*k])?;
        }
        let map = |v: f32| match scale {
            None => v as f64,
            Some(k) => 1.0 + k * v as f64,
        };
        let (lo, hi) = volume.range();
        let (n_lo, n_hi) = (map(lo).min(map(hi)), map(lo).max(map(hi)));
        if n_lo <= 0.0 {
            return Err(c.err(
                &at,
                format!(
                    "the index from grid `{grid}` reaches {n_lo} <= 0 (grid values {lo} to {hi}); the refractive index must be > 0"
                ),
            ));
        }
        m.index = IndexProfile::Constant([n_hi; 3]);
        m.index_grid = Some(GridIndex {
            volume,
            scale: *scale,
        });
    }
    if let RawExtinction::Grid(RawGridMap::Vdb { file, grid, scale }) = &o.extinction {
        let at = [K("object"), I(i), K("extinction")];
        let (file, grid) = source(&at, file, grid)?;
        let volume = volumes.load(c, &at, &file, &grid)?;
        let sp = [&at[..], &[K("scale")]].concat();
        let scale = c.vec3(&sp, *scale)?;
        if scale.min_element() < 0.0 {
            return Err(c.err(&sp, "extinction scale must be >= 0"));
        }
        let (lo, hi) = volume.range();
        if lo < 0.0 && scale.max_element() > 0.0 {
            return Err(c.err(
                &at,
                format!(
                    "grid `{grid}` holds negative values (down to {lo}): extinction would be < 0"
                ),
            ));
        }
        m.extinction = scale * hi as f64;
        if m.extinction.max_element() > MAX_EXTINCTION {
            return Err(c.err(
                &sp,
                format!(
                    "the extinction reaches {:e} (grid maximum {hi} times the scale), over the limit of {MAX_EXTINCTION:e} per world unit",
                    m.extinction.max_element()
                ),
            ));
        }
        m.extinction_grid = Some(GridExtinction { volume, scale });
    }
    Ok(())
}
