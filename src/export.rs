//! `eikon export`: a scene's volumes as OpenVDB grids (for Blender, Houdini
//! and anything built on OpenVDB) and as NumPy arrays.
//!
//! Grid names, units and conventions are documented in docs/SCENES.md
//! ("OpenVDB and NumPy").

use crate::output::{build_medium, write_atomic};
use crate::render::load_light_volumes;
use anyhow::{bail, Context, Result};
use eikon_grid::vdb::{self, Grid, GridClass, GridData, Transform, Tree, VectorType};
use eikon_grid::{GridGeometry, Medium, Scene};
use eikon_wavefront::staging::{new_run_id, tidy, Staging};
use eikon_wavefront::LightVolume;
use ndarray::{s, Array3, Array4, Axis};
use ndarray_npy::WriteNpyExt;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `eikon export`.
#[derive(clap::Args)]
pub struct Args {
    /// Scene file (TOML).
    scene: PathBuf,
    /// Light volumes written by `eikon simulate` (needed for the
    /// `fluence` and `flux` grids). With `--frames`, the output folder of
    /// `eikon simulate --frames`: frame F's in `LIGHT/frame_FFFF/`.
    #[arg(long)]
    light: Option<PathBuf>,
    /// OpenVDB file to write (several grids in one file). With `--frames`,
    /// frame F goes to `NAME_FFFF.vdb`: a sequence Blender imports as one
    /// animated volume; the frames' manifest (`manifest-export.json`) is
    /// kept in its folder.
    #[arg(long)]
    vdb: Option<PathBuf>,
    /// Directory for one NumPy `.npy` file per grid and `volumes.json`
    /// (created if missing). With `--frames`, frame F's in
    /// `DIR/frame_FFFF/`; the directory must lie in the `--vdb`'s folder
    /// when both are given.
    #[arg(long)]
    npy: Option<PathBuf>,
    /// Grids to export, comma-separated, from n, grad_n, sigma_t,
    /// fluence, flux [default: all; fluence and flux only with --light].
    #[arg(long, value_delimiter = ',')]
    grids: Option<Vec<String>>,
    /// Store VDB values as 16-bit half floats (about 3 significant digits;
    /// half the size).
    #[arg(long)]
    half: bool,
    /// Do not zip-compress the VDB values (larger file, faster to write).
    #[arg(long)]
    uncompressed: bool,
    /// Print what was written as JSON (not with `--frames`: `eikon status
    /// FOLDER --json` reports a frame run).
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    grid: crate::grid::GridFlags,
    #[command(flatten)]
    frames: crate::frames::FrameFlags,
}

/// The largest finite half float.
const HALF_MAX: f32 = 65504.0;

/// The volumes `--grids` can name.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Key {
    N,
    GradN,
    SigmaT,
    Fluence,
    Flux,
}

const KEYS: [(&str, Key); 5] = [
    ("n", Key::N),
    ("grad_n", Key::GradN),
    ("sigma_t", Key::SigmaT),
    ("fluence", Key::Fluence),
    ("flux", Key::Flux),
];

/// The values of one exported volume, on the scene's grid.
enum Values {
    /// `(nx, ny, nz)`.
    Float(Array3<f32>, f32),
    /// `(nx, ny, nz, 3)`.
    Vec3(Array4<f32>, [f32; 3], VectorType),
}

/// One exported volume: a VDB grid and a `.npy` file.
struct Volume {
    name: String,
    class: GridClass,
    units: &'static str,
    description: String,
    values: Values,
}

fn parse_keys(args: &Args) -> Result<Vec<Key>> {
    let Some(names) = &args.grids else {
        let n = if args.light.is_some() { 5 } else { 3 };
        return Ok(KEYS[..n].iter().map(|k| k.1).collect());
    };
    let mut keys = Vec::new();
    for name in names {
        let name = name.trim();
        let Some(&(_, k)) = KEYS.iter().find(|(n, _)| *n == name) else {
            bail!(
                "--grids: unknown grid `{name}` (choose from {})",
                KEYS.map(|k| k.0).join(", ")
            );
        };
        if matches!(k, Key::Fluence | Key::Flux) && args.light.is_none() {
            bail!("--grids {name}: needs --light OUT/ (the output of `eikon simulate` for this scene)");
        }
        if !keys.contains(&k) {
            keys.push(k);
        }
    }
    if keys.is_empty() {
        bail!("--grids: no grid named");
    }
    Ok(keys)
}

/// `base`, or `base_r`, `base_g`, `base_b` for three colour channels.
fn channel_name(base: &str, channel: usize, channels: usize) -> String {
    if channels == 1 {
        base.to_string()
    } else {
        format!("{base}_{}", ["r", "g", "b"][channel])
    }
}

/// The volumes `keys` ask for, in a fixed order.
fn volumes(scene: &Scene, medium: &Medium, lights: &[LightVolume], keys: &[Key]) -> Vec<Volume> {
    let g = &medium.geometry;
    let [nx, ny, nz] = g.dims;
    let channels = medium.channels();
    let mut out = Vec::new();
    if keys.contains(&Key::N) {
        for c in 0..channels {
            // The ambient index is constant (a number per channel).
            let background = scene.ambient.index.value(g.min, c) as f32;
            out.push(Volume {
                name: channel_name("n", c, channels),
                class: GridClass::Unknown,
                units: "1",
                description: "refractive index (smoothed, as traced)".into(),
                values: Values::Float(
                    medium.index[c].slice(s![.., .., .., 0]).to_owned(),
                    background,
                ),
            });
        }
    }
    if keys.contains(&Key::GradN) {
        for c in 0..channels {
            let grad = Array4::from_shape_fn((nx, ny, nz, 3), |(i, j, k, a)| {
                medium.gradient_at(c, i, j, k)[a] as f32
            });
            out.push(Volume {
                name: channel_name("grad_n", c, channels),
                class: GridClass::Unknown,
                units: "1/world unit",
                description: "gradient of the refractive index".into(),
                values: Values::Vec3(grad, [0.0; 3], VectorType::Covariant),
            });
        }
    }
    if keys.contains(&Key::SigmaT) {
        let density = medium.extinction.mean_axis(Axis(3)).expect("3 channels");
        out.push(Volume {
            name: "density".into(),
            class: GridClass::FogVolume,
            units: "1/world unit",
            description: "extinction sigma_t, mean of R, G, B".into(),
            values: Values::Float(density, 0.0),
        });
        out.push(Volume {
            name: "sigma_t".into(),
            class: GridClass::Unknown,
            units: "1/world unit",
            description: "extinction sigma_t, R, G, B".into(),
            values: Values::Vec3(medium.extinction.clone(), [0.0; 3], VectorType::Invariant),
        });
    }
    let several = lights.len() > 1;
    if keys.contains(&Key::Fluence) && !lights.is_empty() {
        // All lights together, then each light (when there are several).
        let mut total = Array4::<f32>::zeros((nx, ny, nz, 3));
        for l in lights {
            total += &l.fluence;
        }
        let mut sets = vec![(String::new(), "all lights".to_string(), total)];
        if several {
            sets.extend(
                lights
                    .iter()
                    .enumerate()
                    .map(|(i, l)| (format!("_{i}"), format!("light {i}"), l.fluence.clone())),
            );
        }
        for (suffix, who, rgb) in sets {
            let mean = rgb.mean_axis(Axis(3)).expect("3 channels");
            out.push(Volume {
                name: format!("fluence{suffix}"),
                class: GridClass::FogVolume,
                units: "W/world unit^2",
                description: format!("fluence rate, mean of R, G, B, {who}"),
                values: Values::Float(mean, 0.0),
            });
            out.push(Volume {
                name: format!("fluence_rgb{suffix}"),
                class: GridClass::Unknown,
                units: "W/world unit^2",
                description: format!("fluence rate, R, G, B, {who}"),
                values: Values::Vec3(rgb, [0.0; 3], VectorType::Invariant),
            });
        }
    }
    if keys.contains(&Key::Flux) {
        for (i, l) in lights.iter().enumerate() {
            let base = if several {
                format!("flux_{i}")
            } else {
                "flux".into()
            };
            for (c, f) in l.flux.iter().enumerate() {
                out.push(Volume {
                    name: channel_name(&base, c, l.flux.len()),
                    class: GridClass::Unknown,
                    units: "W/world unit^2",
                    description: format!("net flux vector (vector irradiance) of light {i}"),
                    values: Values::Vec3(f.clone(), [0.0; 3], VectorType::ContravariantRelative),
                });
            }
        }
    }
    out
}

/// The volume as a VDB grid: active where it differs from the background.
fn to_grid(v: &Volume, transform: Transform, half: bool) -> Grid {
    let data = match &v.values {
        Values::Float(a, bg) => {
            let (nx, ny, nz) = a.dim();
            GridData::Float(Tree::from_dense([nx, ny, nz], [0; 3], *bg, |[i, j, k]| {
                a[[i, j, k]]
            }))
        }
        Values::Vec3(a, bg, vt) => {
            let (nx, ny, nz, _) = a.dim();
            let tree = Tree::from_dense([nx, ny, nz], [0; 3], *bg, |[i, j, k]| {
                [a[[i, j, k, 0]], a[[i, j, k, 1]], a[[i, j, k, 2]]]
            });
            GridData::Vec3(tree, *vt)
        }
    };
    Grid {
        name: v.name.clone(),
        class: v.class,
        transform,
        half,
        data,
    }
}

/// Run `eikon export`.
pub fn run(args: Args) -> Result<()> {
    if args.vdb.is_none() && args.npy.is_none() {
        bail!("nothing to write: give --vdb FILE.vdb and/or --npy DIR/");
    }
    let keys = parse_keys(&args)?;
    if let Some(dir) = &args.npy {
        if dir.exists() && !dir.is_dir() {
            bail!("{}: --npy: exists and is not a directory", dir.display());
        }
    }
    if args.frames.frames.is_some() {
        return run_frames(&args, &keys);
    }
    let scene = args.grid.load(&args.scene)?;
    let medium = build_medium(&scene)?;
    let lights = match &args.light {
        Some(dir) => load_light_volumes(dir, &scene, &medium)?,
        None => Vec::new(),
    };
    let summary = export(
        &args,
        &scene,
        &medium,
        &lights,
        &keys,
        args.vdb.as_deref(),
        args.npy.as_deref(),
    )?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        print_summary(&summary, medium.geometry.voxel_count() as u64);
    }
    Ok(())
}

/// `eikon export --frames`: frame F's grids to `NAME_FFFF.vdb` and
/// `DIR/frame_FFFF/`, from `LIGHT/frame_FFFF/`, the medium built once when
/// no object moves.
fn run_frames(args: &Args, keys: &[Key]) -> Result<()> {
    use crate::frames::{
        check_light_frames, folder_of, frame_dir, numbered, relative_to, Job, Media, Output, Plan,
    };
    if args.json {
        bail!("--json: not with --frames (`eikon status FOLDER --json` reports a frame run)");
    }
    let folder = match (&args.vdb, &args.npy) {
        (Some(v), _) => folder_of(v),
        (None, Some(d)) => d.clone(),
        (None, None) => unreachable!("checked by run"),
    };
    let vdb_name: Option<PathBuf> = args
        .vdb
        .as_ref()
        .map(|v| PathBuf::from(v.file_name().unwrap_or_default()));
    let npy_dir: Option<PathBuf> = match &args.npy {
        Some(d) => Some(relative_to(&folder, d).with_context(|| {
            format!(
                "{}: --npy: with --frames and --vdb, the arrays' folder must lie in the --vdb's folder ({}), where the frames' manifest is kept",
                d.display(),
                folder.display()
            )
        })?),
        None => None,
    };
    let anim = args.grid.load_animation(&args.scene)?;
    let plan = Plan::new(&args.frames, &args.scene, &anim)?;
    if let Some(light) = &args.light {
        check_light_frames(light, plan.frames())?;
    }
    let settings = format!(
        "grids {keys:?}; light {}; vdb {}; npy {}; half {}; zip {}; grid {:?}",
        args.light
            .as_ref()
            .map_or("none".to_string(), |l| l.display().to_string()),
        vdb_name
            .as_ref()
            .map_or("none".to_string(), |v| v.display().to_string()),
        npy_dir
            .as_ref()
            .map_or("none".to_string(), |d| format!("{}/", d.display())),
        args.half,
        !args.uncompressed,
        args.grid.grid_override()
    );
    let mut job = Job::open(&folder, "export", &plan, settings, false)?;
    job.lit_by(args.light.as_deref());
    let mut media = Media::new(&anim, false);
    job.run(|f| {
        let scene = anim.frame(f)?;
        let (medium, note) = media.of(&scene)?;
        let lights = match &args.light {
            Some(l) => load_light_volumes(&frame_dir(l, f), &scene, &medium)?,
            None => Vec::new(),
        };
        let vdb = vdb_name.as_ref().map(|v| numbered(v, f));
        let npy = npy_dir.as_ref().map(|d| frame_dir(d, f));
        let summary = export(
            args,
            &scene,
            &medium,
            &lights,
            keys,
            vdb.as_ref().map(|v| folder.join(v)).as_deref(),
            npy.as_ref().map(|d| folder.join(d)).as_deref(),
        )?;
        let mut files: Vec<PathBuf> = vdb.into_iter().collect();
        if let Some(d) = npy {
            for name in summary["npy"]["files"].as_array().into_iter().flatten() {
                files.push(d.join(name.as_str().expect("file names")));
            }
            files.push(d.join(NPY_SIDECAR));
        }
        Ok(Output {
            files,
            note: note.to_string(),
            pending: false,
        })
    })
}

/// Export the `keys` volumes of `scene` (built as `medium`, lit by
/// `lights`) to the OpenVDB file `vdb` and/or the folder `npy`: a summary
/// of what was written.
fn export(
    args: &Args,
    scene: &Scene,
    medium: &Medium,
    lights: &[LightVolume],
    keys: &[Key],
    vdb: Option<&Path>,
    npy: Option<&Path>,
) -> Result<Value> {
    let volumes = volumes(scene, medium, lights, keys);
    let geometry = &medium.geometry;
    let transform = Transform::for_grid(geometry);
    let mut summary = json!({
        "scene": args.scene.display().to_string(),
        "grid": {
            "dims": geometry.dims,
            "min": geometry.min.to_array(),
            "max": geometry.max.to_array(),
        },
    });

    if let Some(path) = vdb {
        if args.half {
            for v in &volumes {
                let data = match &v.values {
                    Values::Float(a, _) => a.as_slice(),
                    Values::Vec3(a, ..) => a.as_slice(),
                };
                let over = data
                    .expect("standard layout")
                    .iter()
                    .filter(|x| x.is_finite() && x.abs() > HALF_MAX)
                    .count();
                if over > 0 {
                    eprintln!(
                        "warning: grid `{}`: {over} value(s) exceed the half-float range (+-{HALF_MAX}) and are stored as infinite; export without --half to keep them",
                        v.name
                    );
                }
            }
        }
        let t = Instant::now();
        let grids: Vec<Grid> = volumes
            .iter()
            .map(|v| to_grid(v, transform, args.half))
            .collect();
        let options = vdb::WriteOptions {
            zip: !args.uncompressed,
        };
        let mut report = None;
        write_atomic(path, |w| {
            report = Some(
                vdb::write(w, &grids, &options)
                    .with_context(|| format!("{}: writing OpenVDB", path.display()))?,
            );
            Ok(())
        })?;
        let seconds = t.elapsed().as_secs_f64();
        let report = report.expect("written");
        let dense: u64 = volumes
            .iter()
            .map(|v| match v.values {
                Values::Float(..) => 4,
                Values::Vec3(..) => 12,
            })
            .sum::<u64>()
            * geometry.voxel_count() as u64;
        summary["vdb"] = json!({
            "file": path.display().to_string(),
            "bytes": report.bytes,
            "dense_float32_bytes": dense,
            "seconds": seconds,
            "half": args.half,
            "zip": options.zip,
            "grids": report.grids.iter().map(|g| json!({
                "name": g.name,
                "type": g.grid_type,
                "active_voxels": g.active_voxels,
                "leaves": g.leaves,
                "tiles": g.tiles,
                "bytes": g.bytes,
            })).collect::<Vec<_>>(),
        });
    }

    if let Some(dir) = npy {
        write_npy_dir(dir, &args.scene, geometry, &transform, &volumes)?;
        summary["npy"] = json!({
            "dir": dir.display().to_string(),
            "files": volumes.iter().map(|v| format!("{}.npy", v.name)).collect::<Vec<_>>(),
        });
    }

    Ok(summary)
}

/// The sidecar of an `--npy` folder.
pub const NPY_SIDECAR: &str = "volumes.json";

/// Write one `.npy` per volume and [`NPY_SIDECAR`] into `dir` as one run
/// (`eikon_wavefront::staging`): the arrays to temporaries, renamed into
/// place once all are complete, the sidecar last, naming a fresh run id and
/// every array's size and CRC-32 so a reader can tell a folder a killed
/// re-export left half-updated. Arrays of an earlier export that this one
/// does not write again are removed; other files are left alone.
fn write_npy_dir(
    dir: &Path,
    scene: &Path,
    geometry: &GridGeometry,
    transform: &Transform,
    volumes: &[Volume],
) -> Result<()> {
    std::fs::create_dir_all(dir)
        .with_context(|| format!("{}: cannot create the --npy directory", dir.display()))?;
    let sidecar_path = dir.join(NPY_SIDECAR);
    let before: Vec<String> = std::fs::read(&sidecar_path)
        .ok()
        .and_then(|b| serde_json::from_slice::<Value>(&b).ok())
        .map(|v| {
            v["volumes"]
                .as_array()
                .into_iter()
                .flatten()
                .filter_map(|e| e["file"].as_str().map(str::to_string))
                .collect()
        })
        .unwrap_or_default();
    let mut staging = Staging::new();
    let mut list = Vec::new();
    for v in volumes {
        let file = format!("{}.npy", v.name);
        let path = dir.join(&file);
        let (shape, background): (Vec<usize>, Value) = match &v.values {
            Values::Float(a, bg) => {
                staging.add(&path, |w| a.write_npy(w))?;
                (a.shape().to_vec(), json!(bg))
            }
            Values::Vec3(a, bg, _) => {
                staging.add(&path, |w| a.write_npy(w))?;
                (a.shape().to_vec(), json!(bg))
            }
        };
        let mut entry = json!({
            "name": v.name,
            "file": file,
            "shape": shape,
            "dtype": "float32",
            "units": v.units,
            "description": v.description,
            "background": background,
            "class": v.class.as_str(),
        });
        if let Values::Vec3(_, _, vt) = &v.values {
            entry["vector_type"] = json!(vt.as_str());
        }
        list.push(entry);
    }
    let sidecar = json!({
        "format": "eikon-volumes",
        "version": 2,
        "run_id": new_run_id(),
        "scene": scene.display().to_string(),
        "grid": {
            "dims": geometry.dims,
            "min": geometry.min.to_array(),
            "max": geometry.max.to_array(),
            "spacing": geometry.spacing().to_array(),
        },
        "axis_order": "array[i, j, k] (and [i, j, k, c] for vectors, c = x, y, z or R, G, B) is the cell centred at min + (i + 0.5, j + 0.5, k + 0.5) * spacing: x slowest, z fastest (C order); it is VDB voxel (i, j, k)",
        "vdb_transform": {
            "voxel_size": transform.voxel_size.to_array(),
            "translation": transform.translation.to_array(),
        },
        "volumes": list,
        "files": staging.files(),
    });
    staging.add(&sidecar_path, |w| {
        serde_json::to_writer_pretty(&mut *w, &sidecar)?;
        w.write_all(b"\n").map_err(serde_json::Error::io)
    })?;
    staging.commit()?;
    tidy(
        dir,
        &before,
        |f| volumes.iter().any(|v| f == format!("{}.npy", v.name)),
        |f| f == NPY_SIDECAR || f.ends_with(".npy"),
    );
    Ok(())
}

fn mib(b: u64) -> String {
    format!("{:.2} MiB", b as f64 / (1024.0 * 1024.0))
}

fn print_summary(s: &Value, voxels: u64) {
    if let Some(v) = s.get("vdb") {
        let bytes = v["bytes"].as_u64().unwrap_or(0);
        let dense = v["dense_float32_bytes"].as_u64().unwrap_or(0);
        println!(
            "wrote {}: {} grids, {} ({:.1}x smaller than dense float32, {}), {:.2} s",
            v["file"].as_str().unwrap_or(""),
            v["grids"].as_array().map_or(0, |g| g.len()),
            mib(bytes),
            dense as f64 / bytes.max(1) as f64,
            mib(dense),
            v["seconds"].as_f64().unwrap_or(0.0)
        );
        for g in v["grids"].as_array().into_iter().flatten() {
            let active = g["active_voxels"].as_u64().unwrap_or(0);
            println!(
                "  {:<14} {:<28} {:>10} active voxels ({:5.1}%), {:>6} leaves, {:>6} tiles, {}",
                g["name"].as_str().unwrap_or(""),
                g["type"].as_str().unwrap_or(""),
                active,
                100.0 * active as f64 / voxels.max(1) as f64,
                g["leaves"],
                g["tiles"],
                mib(g["bytes"].as_u64().unwrap_or(0))
            );
        }
    }
    if let Some(n) = s.get("npy") {
        println!(
            "wrote {} .npy files and volumes.json to {}",
            n["files"].as_array().map_or(0, |f| f.len()),
            n["dir"].as_str().unwrap_or("")
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn channel_names() {
        assert_eq!(channel_name("n", 0, 1), "n");
        assert_eq!(channel_name("grad_n", 2, 3), "grad_n_b");
    }
}
