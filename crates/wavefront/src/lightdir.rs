//! The light-volume folder: what `eikon simulate` writes and what
//! `eikon render --light`, `eikon probe` and `eikon export --light` read.
//! One [`write()`] and one reader ([`LightDir`]), so the format lives here
//! and nowhere else.
//!
//! # Layout (format version 3)
//! * `lightI_fluence.npy`: light `I`'s fluence, `(nx, ny, nz, 3)`
//!   little-endian float32 ([`LightVolume::fluence`]);
//! * `lightI_flux.npy`: its net flux vector, `(nx, ny, nz, 3)`, or
//!   `(3, nx, ny, nz, 3)` per colour channel with dispersion;
//! * `light_volumes.json` ([`SIDECAR`], a [`Sidecar`]): the grid, the
//!   lights, units, the options and summary of the run, its run id, and the
//!   size and CRC-32 of every file of the run.
//!
//! # A folder holds one whole run
//! The folder is written through [`crate::staging`]: every volume to a
//! temporary beside its final name, renamed into place only when all are
//! complete, the sidecar (a fresh run id and the size and CRC-32 of every
//! file) last. Every reader checks each file's size against the sidecar
//! before reading it, its `.npy` header against its size before
//! allocating, its CRC-32 after reading, and that every value is finite.
//!
//! A re-run killed between its renames leaves new volumes beside the old
//! sidecar: their sizes or checksums disagree with it, and every reader
//! refuses the folder, naming the file, instead of mixing two runs.
//! Otherwise a reader sees the whole old run or the whole new one.
//! Leftover `.NAME.PID.tmp` files of a killed run are never read, and the
//! next complete run into the folder removes them. Files that are not ours
//! (images of `eikon run`, the user's) are left alone.

use crate::staging::{err, new_run_id, plain_name, tidy, Staging};
pub use crate::staging::{Error, FileRecord, RENAME_PAUSE_ENV};
use crate::{LightVolume, Summary};
use eikon_grid::{GridGeometry, Light};
use ndarray::{Array4, ArrayD, Axis, Ix4, IxDyn, ShapeBuilder};
use serde::{Deserialize, Serialize};
use std::fs::File;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

/// The sidecar that describes a light-volume folder.
pub const SIDECAR: &str = "light_volumes.json";

/// The sidecar's `format`.
pub const FORMAT: &str = "eikon-light-volumes";

/// The format version this code writes and reads: 3 added the run id and
/// the files' sizes and checksums (2 stored fluence and flux without them).
pub const VERSION: u32 = 3;

/// `light_volumes.json`: everything about one run of `eikon simulate`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Sidecar {
    /// Always [`FORMAT`].
    pub format: String,
    /// Always [`VERSION`].
    pub version: u32,
    /// A fresh id per run (16 hex digits).
    pub run_id: String,
    /// The scene file simulated.
    pub scene: String,
    /// The grid the volumes sample.
    pub grid: GridRecord,
    /// What the numbers mean.
    pub units: Units,
    /// `wavefront` or `photons`.
    pub method: String,
    /// The settings of the run.
    pub options: RunOptions,
    /// One entry per light, in the scene's order.
    pub lights: Vec<LightRecord>,
    /// Every file of the run with its size and checksum.
    pub files: Vec<FileRecord>,
    /// Where the light was simulated.
    pub backend: String,
    /// Wall time of the whole run.
    pub seconds: f64,
}

/// The grid of a light-volume folder.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct GridRecord {
    /// Cells along x, y, z.
    pub dims: [usize; 3],
    /// Lower corner, world units.
    pub min: [f64; 3],
    /// Upper corner, world units.
    pub max: [f64; 3],
    /// Cell size, world units (`(max - min) / dims`).
    pub spacing: [f64; 3],
    /// Where sample `[i, j, k]` sits.
    pub convention: String,
}

/// The units of a light-volume folder, in words.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Units {
    /// Length.
    pub length: String,
    /// The fluence arrays.
    pub fluence: String,
    /// The flux arrays.
    pub flux: String,
}

impl Default for Units {
    fn default() -> Self {
        Units {
            length: "world units of the scene".into(),
            fluence: "W per world unit^2 (W/m^2 when the unit is the metre), R, G, B: the fluence rate phi, the cell average of the integral of radiance over all directions (track-length estimate; ray families add); with --deposit paper the differential irradiance of the highest-energy ray".into(),
            flux: "W per world unit^2: the net flux vector F (vector irradiance, the first angular moment), cell average; shape (nx, ny, nz, 3) holding the mean of the R, G, B channels' vectors, or (3, nx, ny, nz, 3) per channel with dispersion. In-scattered radiance per unit length is albedo * sigma_t * phi * p_HG(w . F/|F|; g * |F|/phi); a surface of normal N facing the light receives max(0, -F . N)".into(),
        }
    }
}

/// The settings of a run, as recorded.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RunOptions {
    /// Equal-time step, voxels.
    pub step_voxels: f64,
    /// `Euler` or `Rk4`.
    pub integrator: String,
    /// Emitted patch size, voxels.
    pub patch_size_voxels: f64,
    /// Tessellation threshold, voxels.
    pub split_voxels: f64,
    /// Transmittance threshold.
    pub threshold: f64,
    /// `fluence` or `paper`.
    pub deposit: String,
    /// Fresnel transmission at interfaces.
    pub fresnel: bool,
    /// Fresnel-reflected light traced on (absent: it was not, as before
    /// eikon traced it).
    #[serde(default)]
    pub reflections: bool,
    /// Straight runs of several steps through uniform space taken on the CPU
    /// (`Options::runs`; absent: runs as each step's own tube, before they
    /// were deposited in one pass).
    #[serde(default)]
    pub runs: bool,
    /// Photons per light (`--method photons`).
    pub photons: Option<usize>,
    /// Random seed (`--method photons`).
    pub seed: Option<u64>,
}

/// What a light was, as recorded (the power's unit in words).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "lowercase")]
pub enum LightSource {
    /// A plane wave.
    Directional {
        /// Unit direction of travel.
        direction: [f64; 3],
        /// RGB irradiance across the beam.
        power: [f64; 3],
        /// `power`'s unit.
        power_unit: String,
    },
    /// A spherical wave.
    Point {
        /// Where it is.
        position: [f64; 3],
        /// RGB power.
        power: [f64; 3],
        /// `power`'s unit.
        power_unit: String,
    },
    /// A point light restricted to a cone.
    Spot {
        /// Where it is.
        position: [f64; 3],
        /// Cone axis.
        direction: [f64; 3],
        /// Cone half-angle.
        angle_degrees: f64,
        /// Soft edge.
        falloff_degrees: f64,
        /// RGB power of the unrestricted point light.
        power: [f64; 3],
        /// `power`'s unit.
        power_unit: String,
    },
}

impl From<&Light> for LightSource {
    fn from(l: &Light) -> Self {
        match l {
            Light::Directional { direction, power } => LightSource::Directional {
                direction: direction.to_array(),
                power: power.to_array(),
                power_unit: "W/m^2 across the beam".into(),
            },
            Light::Point { position, power } => LightSource::Point {
                position: position.to_array(),
                power: power.to_array(),
                power_unit: "W".into(),
            },
            Light::Spot {
                position,
                direction,
                angle,
                falloff,
                power,
            } => LightSource::Spot {
                position: position.to_array(),
                direction: direction.to_array(),
                angle_degrees: *angle,
                falloff_degrees: *falloff,
                power: power.to_array(),
                power_unit: "W (of the unrestricted point light)".into(),
            },
        }
    }
}

/// One light of a run: what it was, its files, what happened to it.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct LightRecord {
    /// The light.
    #[serde(flatten)]
    pub source: LightSource,
    /// Its fluence array's file name.
    pub fluence_file: String,
    /// Its flux array's file name.
    pub flux_file: String,
    /// The flux array's shape: `[nx, ny, nz, 3]` or `[3, nx, ny, nz, 3]`.
    pub flux_shape: Vec<usize>,
    /// What happened to its wavefront.
    pub summary: LightSummary,
}

/// [`Summary`] as recorded (and printed by `eikon simulate --json`).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct LightSummary {
    /// Steps taken.
    pub steps: usize,
    /// Most patches alive at once.
    pub peak_patches: usize,
    /// Patches emitted.
    pub emitted: usize,
    /// Reflected patches traced on from a surface (absent: none).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub reflections: usize,
    /// How patches ended.
    pub ended: Ended,
    /// Splits held back by the patch limit.
    pub splits_held_back: usize,
    /// The energy account.
    pub energy_w: Energy,
    /// Wall time of this light.
    pub seconds: f64,
}

/// How patches ended.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Ended {
    /// Left the volume.
    pub exited: usize,
    /// Below the transmittance threshold.
    pub absorbed: usize,
    /// Split too faint to follow (their power is trapped).
    pub faint: usize,
    /// At a caustic (the paper's deposit).
    pub caustic: usize,
    /// Alive at the step limit.
    pub step_limit: usize,
    /// Torn at a sharp interface and dropped (absent: none).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub torn: usize,
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

fn is_none_rgb(x: &[f64; 3]) -> bool {
    *x == [0.0; 3]
}

/// The energy account of a light, RGB watts.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Energy {
    /// Entered the volume.
    pub entered: [f64; 3],
    /// Taken out of the beams inside.
    pub absorbed: [f64; 3],
    /// Carried out of the volume.
    pub exited: [f64; 3],
    /// Reflected at interfaces.
    pub reflected: [f64; 3],
    /// Dropped with eliminated patches.
    pub culled: [f64; 3],
    /// Still travelling when no longer followed (the step limit, or too
    /// faint to follow): light held by total internal reflection.
    pub trapped: [f64; 3],
    /// Dropped with patches torn at a sharp interface (absent: none).
    #[serde(default, skip_serializing_if = "is_none_rgb")]
    pub torn: [f64; 3],
    /// [`Summary::energy_imbalance`].
    pub imbalance_relative: f64,
}

impl LightSummary {
    /// The record of `s`, which took `seconds`.
    pub fn new(s: &Summary, seconds: f64) -> Self {
        LightSummary {
            steps: s.steps,
            peak_patches: s.peak_patches,
            emitted: s.emitted,
            reflections: s.reflections,
            ended: Ended {
                exited: s.exited,
                absorbed: s.absorbed,
                faint: s.faint,
                caustic: s.caustic,
                step_limit: s.step_limit,
                torn: s.torn,
            },
            splits_held_back: s.held,
            energy_w: Energy {
                entered: s.entered,
                absorbed: s.absorbed_power,
                exited: s.exited_power,
                reflected: s.reflected_power,
                culled: s.culled_power,
                trapped: s.trapped_power,
                torn: s.torn_power,
                imbalance_relative: s.energy_imbalance(),
            },
            seconds,
        }
    }
}

impl Sidecar {
    /// The grid as geometry.
    pub fn geometry(&self) -> GridGeometry {
        GridGeometry::new(
            self.grid.dims,
            glam::DVec3::from_array(self.grid.min),
            glam::DVec3::from_array(self.grid.max),
        )
    }

    /// The record of file `name`.
    pub fn file(&self, name: &str) -> Option<&FileRecord> {
        self.files.iter().find(|f| f.name == name)
    }
}

/// What a run wrote, besides its volumes: the caller's description.
pub struct Run<'a> {
    /// The scene file simulated.
    pub scene: String,
    /// `wavefront` or `photons`.
    pub method: String,
    /// The settings.
    pub options: RunOptions,
    /// Where it ran.
    pub backend: String,
    /// Wall time.
    pub seconds: f64,
    /// Per light, in the scene's order: the light, its volume, its summary.
    pub lights: Vec<(&'a Light, &'a LightVolume, LightSummary)>,
}

fn write_array<A: ndarray_npy::WriteNpyExt>(
    a: &A,
) -> impl FnOnce(&mut dyn Write) -> Result<(), String> + '_ {
    move |w| {
        a.write_npy(w)
            .map_err(|e| format!("writing NumPy data: {e}"))
    }
}

/// The first non-finite value of `data` (of `shape`, C order): its index.
fn first_non_finite<'a>(
    shape: &[usize],
    data: impl IntoIterator<Item = &'a f32>,
) -> Option<(Vec<usize>, f32)> {
    let (pos, v) = data.into_iter().enumerate().find(|(_, v)| !v.is_finite())?;
    Some((unravel(pos, shape, false), *v))
}

/// The multi-index of flat position `pos` of an array of `shape`.
fn unravel(mut pos: usize, shape: &[usize], fortran: bool) -> Vec<usize> {
    let mut idx = vec![0; shape.len()];
    let axes: Vec<usize> = if fortran {
        (0..shape.len()).collect()
    } else {
        (0..shape.len()).rev().collect()
    };
    for a in axes {
        idx[a] = pos % shape[a].max(1);
        pos /= shape[a].max(1);
    }
    idx
}

fn fmt_index(idx: &[usize]) -> String {
    let parts: Vec<String> = idx.iter().map(usize::to_string).collect();
    format!("[{}]", parts.join(", "))
}

/// Write the volumes of `run` on `grid` into `dir` (created if missing) as
/// one run: volumes first, the sidecar last (see the module docs). Files
/// of an earlier run that this one does not write again are removed once
/// the new sidecar is in place; other files in `dir` are left alone.
/// Refuses volumes holding NaN or infinite values before writing anything.
pub fn write(dir: &Path, grid: &GridGeometry, run: &Run<'_>) -> Result<Sidecar, Error> {
    for (i, (_, v, _)) in run.lights.iter().enumerate() {
        let arrays =
            std::iter::once(("fluence", &v.fluence)).chain(v.flux.iter().map(|f| ("flux", f)));
        for (what, a) in arrays {
            if let Some((idx, x)) = first_non_finite(a.shape(), a.iter()) {
                return Err(err(
                    dir,
                    format!(
                        "light {i}: the simulated {what} is {x} at {}: not written (light volumes must be finite)",
                        fmt_index(&idx)
                    ),
                ));
            }
        }
    }
    std::fs::create_dir_all(dir)
        .map_err(|e| err(dir, format!("cannot create the output directory: {e}")))?;
    let sidecar_path = dir.join(SIDECAR);
    // The files the run now in place names, to remove those this one drops.
    let before: Vec<String> = std::fs::read(&sidecar_path)
        .ok()
        .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
        .map(|v| {
            v["lights"]
                .as_array()
                .into_iter()
                .flatten()
                .flat_map(|l| [&l["fluence_file"], &l["flux_file"]])
                .filter_map(|n| n.as_str().map(str::to_string))
                .collect()
        })
        .unwrap_or_default();

    let mut staging = Staging::new();
    let mut lights = Vec::new();
    for (i, (light, volume, summary)) in run.lights.iter().enumerate() {
        let fluence_file = format!("light{i}_fluence.npy");
        staging.add(&dir.join(&fluence_file), write_array(&volume.fluence))?;
        let flux_file = format!("light{i}_flux.npy");
        let flux_path = dir.join(&flux_file);
        let flux_shape = if volume.flux.len() == 1 {
            staging.add(&flux_path, write_array(&volume.flux[0]))?;
            volume.flux[0].shape().to_vec()
        } else {
            let views: Vec<_> = volume.flux.iter().map(Array4::view).collect();
            let stacked =
                ndarray::stack(Axis(0), &views).map_err(|e| err(&flux_path, e.to_string()))?;
            staging.add(&flux_path, write_array(&stacked))?;
            stacked.shape().to_vec()
        };
        lights.push(LightRecord {
            source: LightSource::from(*light),
            fluence_file,
            flux_file,
            flux_shape,
            summary: summary.clone(),
        });
    }
    let spacing = grid.spacing();
    let sidecar = Sidecar {
        format: FORMAT.into(),
        version: VERSION,
        run_id: new_run_id(),
        scene: run.scene.clone(),
        grid: GridRecord {
            dims: grid.dims,
            min: grid.min.to_array(),
            max: grid.max.to_array(),
            spacing: spacing.to_array(),
            convention: "array index [i, j, k] holds the value at the centre of cell (i, j, k): min + (i + 0.5, j + 0.5, k + 0.5) * spacing".into(),
        },
        units: Units::default(),
        method: run.method.clone(),
        options: run.options.clone(),
        lights,
        files: staging.files(),
        backend: run.backend.clone(),
        seconds: run.seconds,
    };
    // Every volume is complete on disk; the sidecar is renamed last, so
    // until it lands the old sidecar's sizes and checksums refuse the new
    // volumes.
    staging.add(&sidecar_path, |w| {
        serde_json::to_writer_pretty(&mut *w, &sidecar)?;
        w.write_all(b"\n").map_err(serde_json::Error::io)
    })?;
    staging.commit()?;
    tidy(
        dir,
        &before,
        |f| f == SIDECAR || sidecar.file(f).is_some(),
        |f| {
            f == SIDECAR
                || f.strip_prefix("light")
                    .and_then(|r| {
                        r.strip_suffix("_fluence.npy")
                            .or_else(|| r.strip_suffix("_flux.npy"))
                    })
                    .is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
        },
    );
    Ok(sidecar)
}

/// A light-volume folder whose sidecar has been read and checked; the
/// volumes are read by [`LightDir::volumes`].
#[derive(Clone, Debug)]
pub struct LightDir {
    /// The folder.
    pub path: PathBuf,
    /// Its sidecar.
    pub sidecar: Sidecar,
}

/// Read the light-volume folder `dir` whole: its sidecar and every volume,
/// checked (see [`LightDir::open`], [`LightDir::volumes`]).
pub fn read(dir: &Path) -> Result<(Sidecar, Vec<LightVolume>), Error> {
    let d = LightDir::open(dir)?;
    let v = d.volumes()?;
    Ok((d.sidecar, v))
}

impl LightDir {
    /// Read and check the sidecar of `dir`: format and version, the grid
    /// (at least one cell per axis, finite bounds, `max > min`), the
    /// lights' files listed with sizes and checksums, plain file names.
    pub fn open(dir: &Path) -> Result<LightDir, Error> {
        let path = dir.join(SIDECAR);
        let bytes = std::fs::read(&path).map_err(|e| {
            err(
                &path,
                format!(
                    "cannot read the light-volume description (is {} an `eikon simulate` output?): {e}",
                    dir.display()
                ),
            )
        })?;
        let value: serde_json::Value = serde_json::from_slice(&bytes)
            .map_err(|e| err(&path, format!("not valid JSON: {e}")))?;
        if value["format"] != FORMAT {
            return Err(err(&path, "format: not an eikon light-volume description"));
        }
        match value["version"].as_u64() {
            Some(v) if v == u64::from(VERSION) => {}
            Some(v @ (1 | 2)) => {
                return Err(err(
                    &path,
                    format!(
                        "version: {v}: written by an older eikon, without the run id and the checksums every reader now verifies (format {VERSION}): simulate this scene again"
                    ),
                ))
            }
            _ => {
                return Err(err(
                    &path,
                    format!(
                        "version: {} is not {VERSION} (written by a newer eikon?)",
                        value["version"]
                    ),
                ))
            }
        }
        let sidecar: Sidecar = serde_path_to_error::deserialize(value)
            .map_err(|e| err(&path, format!("{}: {}", e.path(), e.inner())))?;
        check_sidecar(&sidecar).map_err(|m| err(&path, m))?;
        Ok(LightDir {
            path: dir.to_path_buf(),
            sidecar,
        })
    }

    /// Read every light's volume, each file checked against the sidecar:
    /// its size before reading, its `.npy` header against its size and
    /// the grid before allocating, its CRC-32, and every value finite.
    pub fn volumes(&self) -> Result<Vec<LightVolume>, Error> {
        let s = &self.sidecar;
        let [nx, ny, nz] = s.grid.dims;
        let grid = s.geometry();
        let mut out = Vec::new();
        for l in &s.lights {
            let fluence = self.array(&l.fluence_file, &[nx, ny, nz, 3])?;
            let flux = self.array(&l.flux_file, &l.flux_shape)?;
            let fluence = fluence
                .into_dimensionality::<Ix4>()
                .expect("shape checked: 4 axes");
            let flux: Vec<Array4<f32>> = if flux.ndim() == 4 {
                vec![flux
                    .into_dimensionality::<Ix4>()
                    .expect("shape checked: 4 axes")]
            } else {
                flux.axis_iter(Axis(0))
                    .map(|a| a.into_dimensionality::<Ix4>().expect("4 axes").to_owned())
                    .collect()
            };
            let v =
                LightVolume::from_arrays(&grid, fluence, flux).map_err(|m| err(&self.path, m))?;
            out.push(v);
        }
        Ok(out)
    }

    /// Read file `name` of the folder as a float32 array of shape `want`.
    fn array(&self, name: &str, want: &[usize]) -> Result<ArrayD<f32>, Error> {
        let record = self
            .sidecar
            .file(name)
            .expect("checked by open: every light's file is listed");
        read_npy_checked(&self.path.join(name), record, want, &self.sidecar.run_id)
    }
}

fn check_sidecar(s: &Sidecar) -> Result<(), String> {
    let g = &s.grid;
    if g.dims.contains(&0) {
        return Err(format!(
            "grid.dims: {:?}: every axis needs at least one cell",
            g.dims
        ));
    }
    let values = g
        .dims
        .iter()
        .try_fold(3usize, |a, &d| a.checked_mul(d))
        .and_then(|n| n.checked_mul(4));
    if values.is_none() {
        return Err(format!("grid.dims: {:?}: too many cells", g.dims));
    }
    for (v, name) in [(g.min, "min"), (g.max, "max"), (g.spacing, "spacing")] {
        if !v.iter().all(|x| x.is_finite()) {
            return Err(format!("grid.{name}: {v:?} is not finite"));
        }
    }
    for a in 0..3 {
        if g.max[a] <= g.min[a] {
            return Err(format!(
                "grid: max {:?} must exceed min {:?} on every axis",
                g.max, g.min
            ));
        }
        let spacing = (g.max[a] - g.min[a]) / g.dims[a] as f64;
        if (g.spacing[a] - spacing).abs() > 1e-9 * spacing {
            return Err(format!(
                "grid.spacing: {:?} is not (max - min) / dims = {spacing} on axis {a}",
                g.spacing
            ));
        }
    }
    if s.lights.is_empty() {
        return Err("lights: no light volumes listed".into());
    }
    if !is_hex(&s.run_id) {
        return Err(format!("run_id: `{}` is not hex digits", s.run_id));
    }
    for f in &s.files {
        if !plain_name(&f.name) {
            return Err(format!(
                "files: `{}` is not a plain file name in the folder",
                f.name
            ));
        }
        if f.crc32.len() != 8 || !is_hex(&f.crc32) {
            return Err(format!(
                "files: {}: crc32 `{}` is not 8 hex digits",
                f.name, f.crc32
            ));
        }
    }
    let [nx, ny, nz] = g.dims;
    for (i, l) in s.lights.iter().enumerate() {
        for name in [&l.fluence_file, &l.flux_file] {
            if !plain_name(name) {
                return Err(format!(
                    "lights[{i}]: `{name}` is not a plain file name in the folder"
                ));
            }
            if s.file(name).is_none() {
                return Err(format!(
                    "lights[{i}]: `{name}` is not listed in files (with its size and checksum)"
                ));
            }
        }
        if l.flux_shape != [nx, ny, nz, 3] && l.flux_shape != [3, nx, ny, nz, 3] {
            return Err(format!(
                "lights[{i}].flux_shape: {:?} is neither {:?} nor {:?}",
                l.flux_shape,
                [nx, ny, nz, 3],
                [3, nx, ny, nz, 3]
            ));
        }
    }
    Ok(())
}

fn is_hex(s: &str) -> bool {
    !s.is_empty() && s.bytes().all(|b| b.is_ascii_hexdigit())
}

/// A `.npy` header: element type, order, shape.
#[derive(Debug, PartialEq)]
struct NpyHeader {
    descr: String,
    fortran: bool,
    shape: Vec<u64>,
}

/// Parse the Python dict literal of a `.npy` header.
fn parse_header(text: &str) -> Result<NpyHeader, String> {
    struct Cur<'a> {
        s: &'a [u8],
        i: usize,
    }
    impl Cur<'_> {
        fn ws(&mut self) {
            while self.i < self.s.len() && self.s[self.i].is_ascii_whitespace() {
                self.i += 1;
            }
        }
        fn peek(&mut self) -> Option<u8> {
            self.ws();
            self.s.get(self.i).copied()
        }
        fn eat(&mut self, c: u8) -> bool {
            if self.peek() == Some(c) {
                self.i += 1;
                true
            } else {
                false
            }
        }
        fn expect(&mut self, c: u8) -> Result<(), String> {
            if self.eat(c) {
                Ok(())
            } else {
                Err(format!("expected `{}` at byte {}", c as char, self.i))
            }
        }
        fn string(&mut self) -> Result<String, String> {
            let q = self.peek().filter(|&c| c == b'\'' || c == b'"');
            let q = q.ok_or_else(|| format!("expected a string at byte {}", self.i))?;
            self.i += 1;
            let start = self.i;
            while self.i < self.s.len() && self.s[self.i] != q {
                if self.s[self.i] == b'\\' {
                    return Err("escapes in header strings are not supported".into());
                }
                self.i += 1;
            }
            if self.i == self.s.len() {
                return Err("unterminated string".into());
            }
            let out = String::from_utf8_lossy(&self.s[start..self.i]).into_owned();
            self.i += 1;
            Ok(out)
        }
        fn word(&mut self) -> &[u8] {
            self.ws();
            let start = self.i;
            while self.i < self.s.len() && self.s[self.i].is_ascii_alphanumeric() {
                self.i += 1;
            }
            &self.s[start..self.i]
        }
    }
    let mut c = Cur {
        s: text.as_bytes(),
        i: 0,
    };
    let (mut descr, mut fortran, mut shape) = (None, None, None);
    c.expect(b'{')?;
    while !c.eat(b'}') {
        let key = c.string()?;
        c.expect(b':')?;
        match key.as_str() {
            "descr" if descr.is_none() => descr = Some(c.string()?),
            "fortran_order" if fortran.is_none() => {
                fortran = Some(match c.word() {
                    b"True" => true,
                    b"False" => false,
                    w => {
                        return Err(format!(
                            "fortran_order: `{}` is not True or False",
                            String::from_utf8_lossy(w)
                        ))
                    }
                })
            }
            "shape" if shape.is_none() => {
                c.expect(b'(')?;
                let mut dims = Vec::new();
                while !c.eat(b')') {
                    let w = c.word();
                    let w = std::str::from_utf8(w).unwrap_or("");
                    let w = w.strip_suffix('L').unwrap_or(w);
                    let d: u64 = w
                        .parse()
                        .map_err(|_| format!("shape: `{w}` is not a whole number that fits"))?;
                    dims.push(d);
                    if !c.eat(b',') {
                        c.expect(b')')?;
                        break;
                    }
                }
                shape = Some(dims);
            }
            k => return Err(format!("unexpected or repeated key `{k}`")),
        }
        if !c.eat(b',') {
            c.expect(b'}')?;
            break;
        }
    }
    if c.peek().is_some() {
        return Err(format!("unexpected text after the dict at byte {}", c.i));
    }
    Ok(NpyHeader {
        descr: descr.ok_or("missing key `descr`")?,
        fortran: fortran.ok_or("missing key `fortran_order`")?,
        shape: shape.ok_or("missing key `shape`")?,
    })
}

fn fmt_shape<T: std::fmt::Display>(shape: &[T]) -> String {
    let parts: Vec<String> = shape.iter().map(T::to_string).collect();
    if parts.len() == 1 {
        format!("({},)", parts[0])
    } else {
        format!("({})", parts.join(", "))
    }
}

/// Read the little-endian float32 `.npy` file at `path`, which `record`
/// (of run `run_id`) describes and whose shape must be `want`: the size is
/// checked against the record before reading and the header's shape
/// against the size before allocating; then the CRC-32 and that every
/// value is finite. Errors name the file (and the first bad index).
pub fn read_npy_checked(
    path: &Path,
    record: &FileRecord,
    want: &[usize],
    run_id: &str,
) -> Result<ArrayD<f32>, Error> {
    let fail = |m: String| err(path, m);
    let mut file = File::open(path).map_err(|e| fail(format!("cannot read: {e}")))?;
    let len = file
        .metadata()
        .map_err(|e| fail(format!("cannot read: {e}")))?
        .len();
    let other_run = format!(
        "not the file {SIDECAR} (run {run_id}) describes: the folder mixes files of two runs (an interrupted `eikon simulate`?) or was changed since: simulate again"
    );
    if len != record.bytes {
        return Err(fail(format!(
            "{len} bytes, but {} recorded: {other_run}",
            record.bytes
        )));
    }
    let mut crc = crc32fast::Hasher::new();
    let mut read = |buf: &mut [u8], crc: &mut crc32fast::Hasher| -> Result<(), Error> {
        file.read_exact(buf)
            .map_err(|e| fail(format!("cannot read: {e}")))?;
        crc.update(buf);
        Ok(())
    };
    // Magic, version, header length.
    let not_npy = || fail("not a NumPy .npy file (bad magic)".into());
    if len < 10 {
        return Err(not_npy());
    }
    let mut pre = [0u8; 10];
    read(&mut pre, &mut crc)?;
    if &pre[..6] != b"\x93NUMPY" {
        return Err(not_npy());
    }
    let (header_len, prefix) = match pre[6] {
        1 => (u64::from(u16::from_le_bytes([pre[8], pre[9]])), 10u64),
        2 | 3 => {
            if len < 12 {
                return Err(not_npy());
            }
            let mut two = [0u8; 2];
            read(&mut two, &mut crc)?;
            (
                u64::from(u32::from_le_bytes([pre[8], pre[9], two[0], two[1]])),
                12,
            )
        }
        v => return Err(fail(format!("NumPy format version {v} is not supported"))),
    };
    if prefix + header_len > len {
        return Err(fail(format!(
            "its header claims {header_len} bytes, but the file holds {len} in all: truncated or corrupt"
        )));
    }
    let mut text = vec![0u8; header_len as usize];
    read(&mut text, &mut crc)?;
    let text = std::str::from_utf8(&text).map_err(|_| fail("header is not text".into()))?;
    let header = parse_header(text).map_err(|m| fail(format!("bad .npy header: {m}")))?;
    if header.descr != "<f4" {
        return Err(fail(format!(
            "holds `{}` values; light volumes are little-endian float32 (`<f4`)",
            header.descr
        )));
    }
    // The header's shape against the file's size, before allocating.
    let data_len = len - prefix - header_len;
    let claimed = header
        .shape
        .iter()
        .try_fold(1u64, |a, &d| a.checked_mul(d))
        .and_then(|n| n.checked_mul(4));
    if claimed != Some(data_len) {
        let claimed = claimed.map_or("more than 2^64".into(), |c| c.to_string());
        return Err(fail(format!(
            "its header claims shape {}, {claimed} bytes of float32, but the file holds {data_len} bytes of data: truncated or corrupt",
            fmt_shape(&header.shape)
        )));
    }
    let shape: Vec<usize> = header.shape.iter().map(|&d| d as usize).collect();
    if shape != want {
        return Err(fail(format!(
            "shape {}, but the grid and {SIDECAR} need {}",
            fmt_shape(&shape),
            fmt_shape(want)
        )));
    }
    let count = (data_len / 4) as usize;
    let mut data: Vec<f32> = Vec::with_capacity(count);
    let mut buf = vec![0u8; (1 << 20).min(data_len as usize)];
    let mut left = data_len as usize;
    while left > 0 {
        let chunk = &mut buf[..left.min(1 << 20)];
        read(chunk, &mut crc)?;
        data.extend(
            chunk
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        );
        left -= chunk.len();
    }
    let crc = format!("{:08x}", crc.finalize());
    if crc != record.crc32 {
        return Err(fail(format!(
            "CRC-32 {crc}, but {} recorded: {other_run}",
            record.crc32
        )));
    }
    if let Some(pos) = data.iter().position(|x| !x.is_finite()) {
        return Err(fail(format!(
            "value {} at index {}: light volumes must be finite",
            data[pos],
            fmt_index(&unravel(pos, &shape, header.fortran))
        )));
    }
    let array = if header.fortran {
        ArrayD::from_shape_vec(IxDyn(&shape).f(), data)
    } else {
        ArrayD::from_shape_vec(IxDyn(&shape), data)
    }
    .expect("length checked against the shape");
    Ok(array.as_standard_layout().into_owned())
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;
    use ndarray_npy::WriteNpyExt;

    fn grid(n: usize) -> GridGeometry {
        GridGeometry::new([n, n + 1, n + 2], DVec3::splat(-1.0), DVec3::splat(1.0))
    }

    fn volume(g: &GridGeometry, seed: f32) -> LightVolume {
        let [nx, ny, nz] = g.dims;
        let a = Array4::from_shape_fn((nx, ny, nz, 3), |(i, j, k, c)| {
            seed + (i * 1000 + j * 100 + k * 10 + c) as f32
        });
        LightVolume {
            fluence: a.clone(),
            flux: vec![a * 0.5],
        }
    }

    fn run<'a>(light: &'a Light, v: &'a LightVolume) -> Run<'a> {
        Run {
            scene: "s.toml".into(),
            method: "wavefront".into(),
            options: RunOptions {
                step_voxels: 0.5,
                integrator: "Rk4".into(),
                patch_size_voxels: 1.0,
                split_voxels: 1.0,
                threshold: 1e-4,
                deposit: "fluence".into(),
                fresnel: true,
                reflections: true,
                runs: true,
                photons: None,
                seed: None,
            },
            backend: "cpu".into(),
            seconds: 0.0,
            lights: vec![(light, v, LightSummary::new(&Summary::default(), 0.0))],
        }
    }

    const LIGHT: Light = Light::Point {
        position: DVec3::ZERO,
        power: DVec3::ONE,
    };

    #[test]
    fn round_trip_and_rewrite() {
        let dir = tempfile::tempdir().unwrap();
        let g = grid(3);
        let v = volume(&g, 1.0);
        std::fs::write(dir.path().join("mine.txt"), "keep").unwrap();
        let s = write(dir.path(), &g, &run(&LIGHT, &v)).unwrap();
        let (back, vols) = read(dir.path()).unwrap();
        assert_eq!(back.run_id, s.run_id);
        assert_eq!(back.files, s.files);
        assert_eq!(vols[0].fluence, v.fluence);
        assert_eq!(vols[0].flux, v.flux);
        // Records match the files as they are.
        for f in &s.files {
            assert_eq!(&FileRecord::of_file(&dir.path().join(&f.name)).unwrap(), f);
        }
        // A second run replaces the first and leaves other files alone.
        let w = volume(&g, 2.0);
        let s2 = write(dir.path(), &g, &run(&LIGHT, &w)).unwrap();
        assert_ne!(s2.run_id, s.run_id);
        let (_, vols) = read(dir.path()).unwrap();
        assert_eq!(vols[0].fluence, w.fluence);
        assert_eq!(std::fs::read(dir.path().join("mine.txt")).unwrap(), b"keep");
        // A killed run's temporaries go with the next run; others stay.
        for stale in [".light0_flux.npy.99999.tmp", ".light_volumes.json.1.tmp"] {
            std::fs::write(dir.path().join(stale), "x").unwrap();
        }
        std::fs::write(dir.path().join(".image.png.7.tmp"), "x").unwrap();
        write(dir.path(), &g, &run(&LIGHT, &w)).unwrap();
        assert!(dir.path().join(".image.png.7.tmp").exists());
        std::fs::remove_file(dir.path().join(".image.png.7.tmp")).unwrap();
        let names: Vec<String> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(".tmp"))
            .collect();
        assert!(names.is_empty(), "{names:?}");
    }

    #[test]
    fn dispersion_flux_round_trips() {
        let dir = tempfile::tempdir().unwrap();
        let g = grid(2);
        let mut v = volume(&g, 1.0);
        v.flux = vec![
            v.fluence.clone() * 1.0,
            v.fluence.clone() * 2.0,
            v.fluence.clone() * 3.0,
        ];
        let s = write(dir.path(), &g, &run(&LIGHT, &v)).unwrap();
        assert_eq!(s.lights[0].flux_shape, vec![3, 2, 3, 4, 3]);
        let (_, vols) = read(dir.path()).unwrap();
        assert_eq!(vols[0].flux, v.flux);
    }

    #[test]
    fn non_finite_volumes_are_not_written() {
        let dir = tempfile::tempdir().unwrap();
        let g = grid(2);
        let mut v = volume(&g, 1.0);
        v.flux[0][[1, 2, 3, 1]] = f32::INFINITY;
        let e = write(&dir.path().join("out"), &g, &run(&LIGHT, &v)).unwrap_err();
        assert!(e.message.contains("flux is inf at [1, 2, 3, 1]"), "{e}");
        assert!(!dir.path().join("out").exists());
    }

    /// Rewrite file `name` of `dir` with `bytes` and record it in the
    /// sidecar, as if the run had written it.
    fn reseal(dir: &Path, name: &str, bytes: &[u8]) {
        std::fs::write(dir.join(name), bytes).unwrap();
        let path = dir.join(SIDECAR);
        let mut s: Sidecar = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
        let r = FileRecord::of_file(&dir.join(name)).unwrap();
        *s.files.iter_mut().find(|f| f.name == name).unwrap() = r;
        std::fs::write(&path, serde_json::to_vec(&s).unwrap()).unwrap();
    }

    fn written(g: &GridGeometry) -> tempfile::TempDir {
        let dir = tempfile::tempdir().unwrap();
        write(dir.path(), g, &run(&LIGHT, &volume(g, 1.0))).unwrap();
        dir
    }

    /// `bytes` of a version 1 `.npy` file with `from` replaced by `to` in
    /// its header, the header's length kept.
    fn edit_header(bytes: &[u8], from: &str, to: &str) -> Vec<u8> {
        let hlen = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
        let text = std::str::from_utf8(&bytes[10..10 + hlen]).unwrap();
        assert!(text.contains(from), "{text}");
        let new = text.trim_end().replace(from, to);
        assert!(new.len() < hlen);
        let mut out = bytes[..10].to_vec();
        out.extend_from_slice(new.as_bytes());
        out.resize(10 + hlen - 1, b' ');
        out.push(b'\n');
        out.extend_from_slice(&bytes[10 + hlen..]);
        out
    }

    #[test]
    fn a_header_claiming_more_than_the_file_is_refused_before_allocating() {
        let g = grid(2);
        let dir = written(&g);
        let name = "light0_fluence.npy";
        let bytes = std::fs::read(dir.path().join(name)).unwrap();
        reseal(
            dir.path(),
            name,
            &edit_header(&bytes, "(2, 3, 4, 3)", "(1000000000000, 1, 1, 3)"),
        );
        let e = read(dir.path()).unwrap_err();
        assert!(e.path.ends_with(name), "{e}");
        assert!(
            e.message.contains("claims shape (1000000000000, 1, 1, 3)"),
            "{e}"
        );
        assert!(e.message.contains("the file holds 288 bytes"), "{e}");
        // Shapes whose size overflows are refused the same way.
        reseal(
            dir.path(),
            name,
            &edit_header(&bytes, "(2, 3, 4, 3)", "(4294967296, 4294967296, 1, 3)"),
        );
        let e = read(dir.path()).unwrap_err();
        assert!(e.message.contains("more than 2^64"), "{e}");
        // A smaller shape leaves bytes over: refused too.
        reseal(
            dir.path(),
            name,
            &edit_header(&bytes, "(2, 3, 4, 3)", "(2, 3, 4, 2)"),
        );
        let e = read(dir.path()).unwrap_err();
        assert!(e.message.contains("claims shape (2, 3, 4, 2)"), "{e}");
    }

    #[test]
    fn nan_is_refused_with_its_file_and_index() {
        let g = grid(2);
        let dir = written(&g);
        let name = "light0_flux.npy";
        let mut bytes = std::fs::read(dir.path().join(name)).unwrap();
        // (1, 2, 3, 2) in a (2, 3, 4, 3) array, after the 128-byte header.
        let flat = ((3 + 2) * 4 + 3) * 3 + 2;
        let at = bytes.len() - 2 * 3 * 4 * 3 * 4 + 4 * flat;
        bytes[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
        reseal(dir.path(), name, &bytes);
        let e = read(dir.path()).unwrap_err();
        assert!(e.path.ends_with(name), "{e}");
        assert!(e.message.contains("NaN at index [1, 2, 3, 2]"), "{e}");
    }

    #[test]
    fn a_changed_or_mixed_file_is_refused() {
        let g = grid(2);
        let a = written(&g);
        let b = tempfile::tempdir().unwrap();
        write(b.path(), &g, &run(&LIGHT, &volume(&g, 7.0))).unwrap();
        // The other run's fluence, same size: the checksum differs.
        std::fs::copy(
            b.path().join("light0_fluence.npy"),
            a.path().join("light0_fluence.npy"),
        )
        .unwrap();
        let e = read(a.path()).unwrap_err();
        assert!(e.path.ends_with("light0_fluence.npy"), "{e}");
        assert!(e.message.contains("CRC-32"), "{e}");
        assert!(e.message.contains("mixes files of two runs"), "{e}");
        // A truncated file: the size differs, refused before reading.
        let p = b.path().join("light0_flux.npy");
        let bytes = std::fs::read(&p).unwrap();
        std::fs::write(&p, &bytes[..bytes.len() - 4]).unwrap();
        let e = read(b.path()).unwrap_err();
        assert!(e.path.ends_with("light0_flux.npy"), "{e}");
        assert!(e.message.contains("412 bytes, but 416 recorded"), "{e}");
    }

    #[test]
    fn bad_sidecars_are_refused_by_name() {
        let g = grid(2);
        let dir = written(&g);
        let path = dir.path().join(SIDECAR);
        let good: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
        use serde_json::json;
        let cases = [
            ("/grid/dims", json!([0, 1, 1]), "grid.dims: [0, 1, 1]"),
            ("/version", json!(2), "version: 2"),
            ("/version", json!(9), "version: 9 is not 3"),
            ("/format", json!("x"), "format"),
            ("/grid/max/1", json!(-2.0), "grid: max"),
            ("/grid/spacing/0", json!(0.1), "grid.spacing"),
            (
                "/lights/0/fluence_file",
                json!("../x.npy"),
                "not a plain file name",
            ),
            ("/files", json!([]), "not listed in files"),
            ("/files/0/crc32", json!("xyz"), "crc32"),
            ("/lights/0/flux_shape", json!([2, 3]), "flux_shape"),
            ("/lights/0/summary", json!(null), "lights[0]"),
            ("/grid/dims", json!("big"), "grid.dims"),
        ];
        for (pointer, value, want) in cases {
            let mut v = good.clone();
            *v.pointer_mut(pointer).unwrap() = value;
            std::fs::write(&path, serde_json::to_vec(&v).unwrap()).unwrap();
            let e = LightDir::open(dir.path()).unwrap_err();
            assert!(e.path.ends_with(SIDECAR), "{e}");
            assert!(e.to_string().contains(want), "missing `{want}` in {e}");
        }
    }

    #[test]
    fn headers_parse() {
        let h =
            parse_header("{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }").unwrap();
        assert_eq!(h.shape, vec![2, 3]);
        assert!(!h.fortran);
        let h =
            parse_header("{\"shape\": (5,), \"fortran_order\": True, \"descr\": \"<f4\"}").unwrap();
        assert_eq!((h.shape, h.fortran), (vec![5], true));
        assert_eq!(
            parse_header("{'descr': '<f4', 'fortran_order': False, 'shape': ()}")
                .unwrap()
                .shape,
            Vec::<u64>::new()
        );
        for bad in [
            "",
            "{'descr': '<f4'}",
            "{'descr': '<f4', 'fortran_order': Maybe, 'shape': (1,)}",
            "{'descr': '<f4', 'fortran_order': False, 'shape': (-1,)}",
            "{'descr': '<f4', 'descr': '<f4', 'fortran_order': False, 'shape': (1,)}",
            "{'descr': '<f4', 'fortran_order': False, 'shape': (1,), 'x': 1}",
        ] {
            assert!(parse_header(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn fortran_order_reads_in_place() {
        let dir = tempfile::tempdir().unwrap();
        let a = ndarray::Array2::from_shape_fn((2, 3), |(i, j)| (i * 10 + j) as f32);
        let mut bytes = Vec::new();
        // The transpose's C-order data is `a`'s Fortran-order data.
        a.t().as_standard_layout().write_npy(&mut bytes).unwrap();
        let bytes = edit_header(&edit_header(&bytes, "False", "True"), "(3, 2)", "(2, 3)");
        let p = dir.path().join("f.npy");
        std::fs::write(&p, &bytes).unwrap();
        let r = FileRecord::of_file(&p).unwrap();
        let back = read_npy_checked(&p, &r, &[2, 3], "0").unwrap();
        assert_eq!(back, a.into_dyn());
    }
}
