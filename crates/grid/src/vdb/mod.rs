//! OpenVDB files: a writer of sparse float and vec3s grids (no Rust crate
//! writes OpenVDB), and import of float grids read through `vdb-rs`.
//!
//! * [`Tree`]: the voxels of one grid, kept as 8^3 leaves; [`write`](fn@write) lays
//!   them out as OpenVDB's standard 5-4-3 tree (root, 32^3 internal nodes,
//!   16^3 internal nodes, 8^3 leaves). Only voxels that differ from the
//!   background are stored (active); a leaf whose 512 voxels are all active
//!   and equal becomes a tile of its 16^3 node, and a 16^3 node made only of
//!   equal active tiles becomes a tile of its 32^3 node. There are never
//!   root-level tiles (vdb-rs would drop them).
//! * [`read_float_grid`]: a float grid of any OpenVDB file, after a
//!   structural check of the whole file (ours, [`inspect`]) that turns
//!   vdb-rs's gaps (vec3s grids read as empty, dropped root tiles, panics on
//!   unknown transforms, half floats with compression, ...) into errors.
//! * [`VdbSolid`]: a float grid as a solid with a distance bound, for scene
//!   objects (`shape = { type = "vdb", ... }`).
//!
//! # Index convention
//! OpenVDB puts voxel centres at integer index coordinates: voxel (i, j, k)
//! is the point `translation + (i, j, k) * voxel_size` and covers half a
//! voxel either side of it. eikon's cell (i, j, k) has its centre at
//! `min + (i + 1/2) * spacing` ([`GridGeometry`]). [`Transform::for_grid`]
//! takes voxel size = spacing and translation = min + spacing / 2, so eikon
//! cell (i, j, k) is VDB voxel (i, j, k), centre on centre, and both cover
//! the same box of the world.
//!
//! # File layout written
//! File format 224 (OpenVDB 6 and later read it), seekable (grid offsets),
//! per-grid compression `COMPRESS_ACTIVE_MASK` (only active values stored),
//! optionally with `COMPRESS_ZIP` (zlib per node; the default). Half floats
//! follow OpenVDB: the grid type gets the suffix `_HalfFloat` and the
//! metadata `is_saved_as_half_float = true`.

mod read;
mod solid;
mod write;

pub use read::{
    inspect, read_float_grid, read_float_tree, FileInfo, FloatGrid, FloatVolume, GridInfo,
    MetaValue,
};
pub use solid::VdbSolid;
pub use write::{write, write_file, GridReport, WriteOptions, WriteReport};

use crate::geometry::GridGeometry;
use glam::DVec3;
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::path::PathBuf;

/// What can go wrong writing or reading a VDB file. Every message names the
/// file (when there is one) and says what is wrong.
#[derive(Debug, thiserror::Error)]
pub enum VdbError {
    /// The file could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// Writing to a stream failed.
    #[error("writing the VDB data failed: {0}")]
    Write(#[from] std::io::Error),
    /// The bytes are not a well-formed OpenVDB file.
    #[error("{}: not a valid OpenVDB file: {message}", path.display())]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// What is wrong, and where.
        message: String,
    },
    /// The file ends too early.
    #[error("{}: truncated: {what} at byte {at} runs past the end of the file ({len} bytes)", path.display())]
    Truncated {
        /// The file.
        path: PathBuf,
        /// What was being read.
        what: String,
        /// Byte offset of the read.
        at: usize,
        /// File length.
        len: usize,
    },
    /// No grid of that name in the file.
    #[error("{}: no grid named `{name}` (the file has: {})", path.display(), if available.is_empty() { "no grids".to_string() } else { available.join(", ") })]
    NoSuchGrid {
        /// The file.
        path: PathBuf,
        /// The name asked for.
        name: String,
        /// The grids there are.
        available: Vec<String>,
    },
    /// The grid is not a float grid.
    #[error("{}: grid `{name}` is a {grid_type} grid; only float grids (Tree_float_5_4_3) can be imported", path.display())]
    WrongType {
        /// The file.
        path: PathBuf,
        /// The grid.
        name: String,
        /// Its type as stored (without the half-float suffix).
        grid_type: String,
    },
    /// Valid OpenVDB, but beyond what the reader (vdb-rs) handles.
    #[error("{}: grid `{name}`: {message}", path.display())]
    Unsupported {
        /// The file.
        path: PathBuf,
        /// The grid ("" for the whole file).
        name: String,
        /// What is not supported, and what to do instead.
        message: String,
    },
    /// Grids that cannot be written as given.
    #[error("cannot write the VDB file: {0}")]
    Invalid(String),
}

/// Shorthand for results of this module.
pub type Result<T> = std::result::Result<T, VdbError>;

/// Index-to-world map of a grid: voxel (i, j, k) has its centre at
/// `translation + (i, j, k) * voxel_size` (OpenVDB's `ScaleTranslateMap`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transform {
    /// Voxel edge along x, y, z, world units.
    pub voxel_size: DVec3,
    /// World position of the centre of voxel (0, 0, 0).
    pub translation: DVec3,
}

impl Transform {
    /// The transform that puts VDB voxel (i, j, k) on eikon cell (i, j, k)
    /// of `geometry` (see the module docs).
    pub fn for_grid(geometry: &GridGeometry) -> Self {
        let h = geometry.spacing();
        Self {
            voxel_size: h,
            translation: geometry.min + 0.5 * h,
        }
    }

    /// World position of index coordinate `ijk` (voxel centres are whole numbers).
    pub fn index_to_world(&self, ijk: DVec3) -> DVec3 {
        self.translation + ijk * self.voxel_size
    }

    /// Continuous index coordinate of world point `p`.
    pub fn world_to_index(&self, p: DVec3) -> DVec3 {
        (p - self.translation) / self.voxel_size
    }

    /// Whether the voxels are cubes (written as `UniformScaleTranslateMap`).
    pub fn is_uniform(&self) -> bool {
        self.voxel_size.x == self.voxel_size.y && self.voxel_size.y == self.voxel_size.z
    }
}

/// OpenVDB's grid class (metadata `class`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GridClass {
    /// No particular meaning.
    Unknown,
    /// A narrow-band signed distance field.
    LevelSet,
    /// A density field, background 0 (what DCC tools render as volume).
    FogVolume,
}

impl GridClass {
    /// The metadata string.
    pub fn as_str(self) -> &'static str {
        match self {
            GridClass::Unknown => "unknown",
            GridClass::LevelSet => "level set",
            GridClass::FogVolume => "fog volume",
        }
    }
}

/// How a vector grid transforms (metadata `vector_type`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VectorType {
    /// Not a spatial vector (colours such as RGB irradiance).
    Invariant,
    /// A gradient.
    Covariant,
    /// A unit normal.
    CovariantNormalize,
    /// A direction or velocity.
    ContravariantRelative,
    /// A position.
    ContravariantAbsolute,
}

impl VectorType {
    /// The metadata string.
    pub fn as_str(self) -> &'static str {
        match self {
            VectorType::Invariant => "invariant",
            VectorType::Covariant => "covariant",
            VectorType::CovariantNormalize => "covariant normalize",
            VectorType::ContravariantRelative => "contravariant relative",
            VectorType::ContravariantAbsolute => "contravariant absolute",
        }
    }
}

/// A voxel value type OpenVDB knows: `f32` (float) or `[f32; 3]` (vec3s).
pub trait VdbValue: Copy + PartialEq + Send + Sync + std::fmt::Debug + 'static {
    /// The value type's name in the tree type (`Tree_<name>_5_4_3`).
    const TYPE_NAME: &'static str;
    /// Append the value as little-endian 32-bit floats.
    fn put(&self, out: &mut Vec<u8>);
    /// Append the value as little-endian 16-bit half floats.
    fn put_half(&self, out: &mut Vec<u8>);
    /// The value rounded to half precision (what a half-float file holds).
    fn to_half_precision(&self) -> Self;
}

impl VdbValue for f32 {
    const TYPE_NAME: &'static str = "float";
    fn put(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.to_le_bytes());
    }
    fn put_half(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&half::f16::from_f32(*self).to_le_bytes());
    }
    fn to_half_precision(&self) -> Self {
        half::f16::from_f32(*self).to_f32()
    }
}

impl VdbValue for [f32; 3] {
    const TYPE_NAME: &'static str = "vec3s";
    fn put(&self, out: &mut Vec<u8>) {
        for c in self {
            c.put(out);
        }
    }
    fn put_half(&self, out: &mut Vec<u8>) {
        for c in self {
            c.put_half(out);
        }
    }
    fn to_half_precision(&self) -> Self {
        self.map(|c| c.to_half_precision())
    }
}

/// Voxels per leaf.
pub(crate) const LEAF_SIZE: usize = 512;

/// One 8^3 leaf: active mask (bit `x << 6 | y << 3 | z` of the local
/// coordinates) and values (background where inactive).
#[derive(Clone, Debug)]
pub(crate) struct Leaf<T> {
    pub mask: [u64; 8],
    pub values: [T; LEAF_SIZE],
}

impl<T: VdbValue> Leaf<T> {
    fn new(background: T) -> Self {
        Self {
            mask: [0; 8],
            values: [background; LEAF_SIZE],
        }
    }

    fn is_on(&self, n: usize) -> bool {
        self.mask[n >> 6] >> (n & 63) & 1 == 1
    }

    pub fn active_count(&self) -> u32 {
        self.mask.iter().map(|w| w.count_ones()).sum()
    }

    /// The value of a full leaf whose voxels are all equal.
    pub fn uniform_value(&self) -> Option<T> {
        let v = self.values[0];
        (self.mask.iter().all(|&w| w == u64::MAX) && self.values.iter().all(|x| *x == v))
            .then_some(v)
    }
}

/// Origin of the leaf holding `ijk`.
pub(crate) fn leaf_origin(ijk: [i32; 3]) -> [i32; 3] {
    ijk.map(|c| c & !7)
}

/// Position of `ijk` in its leaf.
pub(crate) fn leaf_offset(ijk: [i32; 3]) -> usize {
    (((ijk[0] & 7) << 6) | ((ijk[1] & 7) << 3) | (ijk[2] & 7)) as usize
}

/// The voxels of one grid: a background value and the active voxels, in
/// 8^3 leaves keyed by their origin (index coordinates, any sign).
#[derive(Clone, Debug)]
pub struct Tree<T> {
    background: T,
    pub(crate) leaves: BTreeMap<[i32; 3], Box<Leaf<T>>>,
}

impl<T: VdbValue> Tree<T> {
    /// An empty tree: every voxel is the inactive `background`.
    pub fn new(background: T) -> Self {
        Self {
            background,
            leaves: BTreeMap::new(),
        }
    }

    /// The value of inactive voxels.
    pub fn background(&self) -> T {
        self.background
    }

    /// Make voxel `ijk` active with `value` (even if it equals the background).
    pub fn set(&mut self, ijk: [i32; 3], value: T) {
        let bg = self.background;
        let leaf = self
            .leaves
            .entry(leaf_origin(ijk))
            .or_insert_with(|| Box::new(Leaf::new(bg)));
        let n = leaf_offset(ijk);
        leaf.mask[n >> 6] |= 1 << (n & 63);
        leaf.values[n] = value;
    }

    /// Make the `size`^3 voxels from `lo` active with `value`; `lo` and
    /// `size` must be multiples of 8 (a tile of an internal node).
    pub(crate) fn fill_tile(&mut self, lo: [i32; 3], size: i32, value: T) {
        debug_assert!(size % 8 == 0 && lo.iter().all(|c| c % 8 == 0));
        let mut full = Box::new(Leaf::new(self.background));
        full.mask = [u64::MAX; 8];
        full.values = [value; LEAF_SIZE];
        for x in (0..size).step_by(8) {
            for y in (0..size).step_by(8) {
                for z in (0..size).step_by(8) {
                    self.leaves
                        .insert([lo[0] + x, lo[1] + y, lo[2] + z], full.clone());
                }
            }
        }
    }

    /// The value of an active voxel, or `None` where the voxel is inactive.
    pub fn get(&self, ijk: [i32; 3]) -> Option<T> {
        let leaf = self.leaves.get(&leaf_origin(ijk))?;
        let n = leaf_offset(ijk);
        leaf.is_on(n).then(|| leaf.values[n])
    }

    /// A tree from a dense box of `dims` voxels whose voxel (0, 0, 0) is at
    /// index `origin`: voxel `origin + (i, j, k)` takes `value([i, j, k])`
    /// and is active exactly when that differs from `background`. Leaves
    /// are filled in parallel.
    pub fn from_dense(
        dims: [usize; 3],
        origin: [i32; 3],
        background: T,
        value: impl Fn([usize; 3]) -> T + Sync,
    ) -> Self {
        let mut tree = Self::new(background);
        if dims.contains(&0) {
            return tree;
        }
        let end = [0, 1, 2].map(|a| origin[a] + dims[a] as i32);
        let lo = leaf_origin(origin);
        let hi = leaf_origin(end.map(|e| e - 1));
        let count = [0, 1, 2].map(|a| ((hi[a] - lo[a]) / 8 + 1) as usize);
        let leaves: Vec<([i32; 3], Box<Leaf<T>>)> = (0..count[0] * count[1] * count[2])
            .into_par_iter()
            .filter_map(|b| {
                let bi = [
                    b / (count[1] * count[2]),
                    (b / count[2]) % count[1],
                    b % count[2],
                ];
                let o = [0, 1, 2].map(|a| lo[a] + 8 * bi[a] as i32);
                let mut leaf: Option<Box<Leaf<T>>> = None;
                for x in o[0].max(origin[0])..(o[0] + 8).min(end[0]) {
                    for y in o[1].max(origin[1])..(o[1] + 8).min(end[1]) {
                        for z in o[2].max(origin[2])..(o[2] + 8).min(end[2]) {
                            let v = value([
                                (x - origin[0]) as usize,
                                (y - origin[1]) as usize,
                                (z - origin[2]) as usize,
                            ]);
                            if v != background {
                                let leaf =
                                    leaf.get_or_insert_with(|| Box::new(Leaf::new(background)));
                                let n = leaf_offset([x, y, z]);
                                leaf.mask[n >> 6] |= 1 << (n & 63);
                                leaf.values[n] = v;
                            }
                        }
                    }
                }
                leaf.map(|l| (o, l))
            })
            .collect();
        tree.leaves = leaves.into_iter().collect();
        tree
    }

    /// Number of active voxels.
    pub fn active_voxel_count(&self) -> u64 {
        self.leaves.values().map(|l| l.active_count() as u64).sum()
    }

    /// Number of 8^3 leaves holding active voxels (before tiles are formed).
    pub fn leaf_count(&self) -> usize {
        self.leaves.len()
    }

    /// Inclusive index bounding box of the active voxels, or `None` when
    /// there are none.
    pub fn bbox(&self) -> Option<([i32; 3], [i32; 3])> {
        let mut out: Option<([i32; 3], [i32; 3])> = None;
        for (ijk, _) in self.active_voxels() {
            let b = out.get_or_insert((ijk, ijk));
            for (a, &c) in ijk.iter().enumerate() {
                b.0[a] = b.0[a].min(c);
                b.1[a] = b.1[a].max(c);
            }
        }
        out
    }

    /// Every active voxel and its value, leaf by leaf.
    pub fn active_voxels(&self) -> impl Iterator<Item = ([i32; 3], T)> + '_ {
        self.leaves.iter().flat_map(|(o, leaf)| {
            (0..LEAF_SIZE).filter(|&n| leaf.is_on(n)).map(move |n| {
                let ijk = [
                    o[0] + (n >> 6) as i32,
                    o[1] + ((n >> 3) & 7) as i32,
                    o[2] + (n & 7) as i32,
                ];
                (ijk, leaf.values[n])
            })
        })
    }
}

/// The voxels of a grid, by value type.
#[derive(Clone, Debug)]
pub enum GridData {
    /// A `Tree_float_5_4_3` grid.
    Float(Tree<f32>),
    /// A `Tree_vec3s_5_4_3` grid and how its vectors transform.
    Vec3(Tree<[f32; 3]>, VectorType),
}

/// One named grid of a VDB file.
#[derive(Clone, Debug)]
pub struct Grid {
    /// Grid name (unique in a file), e.g. `density`.
    pub name: String,
    /// Grid class (metadata `class`).
    pub class: GridClass,
    /// Index-to-world map.
    pub transform: Transform,
    /// Store values as 16-bit half floats.
    pub half: bool,
    /// The voxels.
    pub data: GridData,
}

impl Grid {
    /// A float grid of class `unknown`, stored as 32-bit floats.
    pub fn float(name: impl Into<String>, tree: Tree<f32>, transform: Transform) -> Self {
        Self {
            name: name.into(),
            class: GridClass::Unknown,
            transform,
            half: false,
            data: GridData::Float(tree),
        }
    }

    /// A vec3s grid of class `unknown`, stored as 32-bit floats.
    pub fn vec3(
        name: impl Into<String>,
        tree: Tree<[f32; 3]>,
        vector_type: VectorType,
        transform: Transform,
    ) -> Self {
        Self {
            name: name.into(),
            class: GridClass::Unknown,
            transform,
            half: false,
            data: GridData::Vec3(tree, vector_type),
        }
    }

    /// The tree type as OpenVDB names it (without the half-float suffix).
    pub fn tree_type(&self) -> String {
        let t = match &self.data {
            GridData::Float(_) => f32::TYPE_NAME,
            GridData::Vec3(..) => <[f32; 3]>::TYPE_NAME,
        };
        format!("Tree_{t}_5_4_3")
    }

    /// Number of active voxels.
    pub fn active_voxel_count(&self) -> u64 {
        match &self.data {
            GridData::Float(t) => t.active_voxel_count(),
            GridData::Vec3(t, _) => t.active_voxel_count(),
        }
    }
}

#[cfg(test)]
mod tests;
