//! `eikon info`: what a scene holds and what building it costs.

use crate::output::fmt_vec;
use anyhow::Result;
use eikon_grid::field::format_bytes;
use eikon_grid::{IndexProfile, Light, Medium, Scene};
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `eikon info`.
#[derive(clap::Args)]
pub struct Args {
    /// Scene file (TOML).
    scene: PathBuf,
    /// Skip building the medium (no index range; instant).
    #[arg(long)]
    no_build: bool,
    /// Print the description as JSON.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    grid: crate::grid::GridFlags,
}

fn describe_index(p: &IndexProfile) -> String {
    match p {
        IndexProfile::Constant([r, g, b]) if r == g && g == b => format!("n = {r}"),
        IndexProfile::Constant([r, g, b]) => format!("n = ({r}, {g}, {b}) R,G,B"),
        IndexProfile::Luneburg { outer, .. } => {
            format!("Luneburg n = {outer} sqrt(2 - (r/R)^2)")
        }
        IndexProfile::Linear {
            n0,
            gradient,
            origin,
        } => format!(
            "linear n = {n0} + {} . (x - {})",
            fmt_vec(*gradient),
            fmt_vec(*origin)
        ),
    }
}

fn describe_light(l: &Light) -> String {
    match l {
        Light::Directional { direction, power } => {
            format!(
                "directional along {}, {} W/m^2",
                fmt_vec(*direction),
                fmt_vec(*power)
            )
        }
        Light::Point { position, power } => {
            format!("point at {}, {} W", fmt_vec(*position), fmt_vec(*power))
        }
        Light::Spot {
            position,
            direction,
            angle,
            falloff,
            power,
        } => format!(
            "spot at {} along {}, half-angle {angle} deg (falloff {falloff}), {} W",
            fmt_vec(*position),
            fmt_vec(*direction),
            fmt_vec(*power)
        ),
    }
}

/// Run `eikon info`.
pub fn run(args: Args) -> Result<()> {
    let scene = Scene::load_with(&args.scene, &args.grid.grid_override())?;
    let g = &scene.grid.geometry;
    let mem = Medium::memory_estimate(&scene);
    let built = if args.no_build {
        None
    } else {
        let t = Instant::now();
        let m = crate::output::build_medium(&scene)?;
        let secs = t.elapsed().as_secs_f64();
        let (lo, hi) = m.index_range();
        let bmax = m.boundary.iter().copied().fold(0f32, f32::max);
        Some((lo, hi, bmax, secs))
    };
    let objects: Vec<_> = scene
        .precedence()
        .iter()
        .map(|&i| {
            let o = &scene.objects[i];
            json!({
                "name": o.name,
                "shape": o.shape.kind(),
                "priority": o.priority,
                "index": describe_index(&o.material.index),
                "extinction": o.material.extinction.to_array(),
                "albedo": o.material.albedo.to_array(),
                "g": o.material.g,
                "emission": o.material.emission.to_array(),
            })
        })
        .collect();
    if args.json {
        let mut v = json!({
            "scene": args.scene.display().to_string(),
            "resolution": g.dims,
            "bounds": { "min": g.min.to_array(), "max": g.max.to_array() },
            "voxel_size": g.spacing().to_array(),
            "smoothing": scene.grid.smoothing,
            "interfaces": scene.grid.interfaces.name(),
            "supersample": scene.grid.supersample,
            "dispersion": scene.grid.dispersion,
            "memory_bytes": { "resident": mem.resident as f64, "peak": mem.peak as f64 },
            "ambient_index": describe_index(&scene.ambient.index),
            "objects": objects,
            "lights": scene.lights.iter().map(describe_light).collect::<Vec<_>>(),
        });
        if let Some((lo, hi, bmax, secs)) = built {
            v["index_range"] = json!([lo, hi]);
            v["boundary_max"] = json!(bmax);
            v["build_seconds"] = json!(secs);
        }
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    println!("scene        {}", args.scene.display());
    println!(
        "resolution   {} x {} x {} voxels ({} in all)",
        g.dims[0],
        g.dims[1],
        g.dims[2],
        g.voxel_count()
    );
    println!(
        "bounds       {} .. {} (world units)",
        fmt_vec(g.min),
        fmt_vec(g.max)
    );
    println!("voxel size   {}", fmt_vec(g.spacing()));
    println!(
        "smoothing    sigma {} voxels; supersampling {}^3; dispersion {}",
        scene.grid.smoothing,
        scene.grid.supersample,
        if scene.grid.dispersion {
            "on (R, G, B index fields)"
        } else {
            "off"
        }
    );
    println!("interfaces   {}", scene.grid.interfaces.name());
    let (light, counters) = crate::grid::light_volume_bytes(&scene);
    println!(
        "memory       {} resident, {} peak while building; light volumes {} (+{} while simulating one light)",
        format_bytes(mem.resident),
        format_bytes(mem.peak),
        format_bytes(light),
        format_bytes(counters)
    );
    if let Some((lo, hi, bmax, secs)) = built {
        println!("index range  {lo:.5} .. {hi:.5} (voxelized and smoothed; built in {secs:.2} s)");
        println!("boundary     peak indicator {bmax:.3} per world unit");
    }
    println!("ambient      {}", describe_index(&scene.ambient.index));
    println!(
        "objects      {} (highest priority first)",
        scene.objects.len()
    );
    for &i in scene.precedence() {
        let o = &scene.objects[i];
        let m = &o.material;
        println!(
            "  {:<16} {:<20} priority {:>3}  {}  extinction {}  albedo {}  g {}",
            o.name,
            o.shape.kind(),
            o.priority,
            describe_index(&m.index),
            fmt_vec(m.extinction),
            fmt_vec(m.albedo),
            m.g
        );
    }
    println!("lights       {}", scene.lights.len());
    for l in &scene.lights {
        println!("  {}", describe_light(l));
    }
    if let Some(r) = &scene.receiver {
        println!(
            "receiver     plane through {} facing {}, albedo {}",
            fmt_vec(r.point),
            fmt_vec(r.normal),
            fmt_vec(r.albedo)
        );
    }
    Ok(())
}
