//! `eikon probe`: the light at one point of simulated light volumes.

use crate::output::{fmt_vec, parse_vec3};
use anyhow::{bail, Result};
use eikon_wavefront::lightdir::LightDir;
use glam::DVec3;
use ndarray::Array4;
use serde_json::{json, Value};
use std::path::PathBuf;

/// Arguments of `eikon probe`.
#[derive(clap::Args)]
pub struct Args {
    /// Directory written by `eikon simulate`.
    volumes: PathBuf,
    /// World point x,y,z.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    at: DVec3,
    /// Print the result as JSON.
    #[arg(long)]
    json: bool,
}

/// Trilinear interpolation (cell-centre convention) of the last-axis
/// vector of `a`, `(nx, ny, nz, 3)`, at continuous voxel `u`.
fn trilinear(a: &Array4<f32>, u: DVec3) -> DVec3 {
    let dims = [a.shape()[0], a.shape()[1], a.shape()[2]];
    let hi = DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64) - 1.0;
    let u = u.clamp(DVec3::ZERO, hi.max(DVec3::ZERO));
    let i0 = [0, 1, 2].map(|k| (u[k] as usize).min(dims[k].saturating_sub(2)));
    let f = [0, 1, 2].map(|k| u[k] - i0[k] as f64);
    let mut out = DVec3::ZERO;
    for corner in 0..8 {
        let d = [corner & 1, (corner >> 1) & 1, (corner >> 2) & 1];
        let mut w = 1.0;
        let mut idx = [0; 3];
        for k in 0..3 {
            idx[k] = (i0[k] + d[k]).min(dims[k] - 1);
            w *= if d[k] == 1 { f[k] } else { 1.0 - f[k] };
        }
        for c in 0..3 {
            out[c] += w * a[[idx[0], idx[1], idx[2], c]] as f64;
        }
    }
    out
}

/// Run `eikon probe`.
pub fn run(args: Args) -> Result<()> {
    // The sidecar checks the grid (at least one cell per axis) and every
    // file against its size, header, checksum and finiteness.
    let folder = LightDir::open(&args.volumes)?;
    let geometry = folder.sidecar.geometry();
    let (min, max) = (geometry.min, geometry.max);
    if !(args.at.cmpge(min).all() && args.at.cmple(max).all()) {
        bail!(
            "--at: {} lies outside the volume {} .. {}",
            fmt_vec(args.at),
            fmt_vec(min),
            fmt_vec(max)
        );
    }
    let u = (args.at - min) / geometry.spacing() - 0.5;
    let out: Vec<(DVec3, Vec<DVec3>)> = folder
        .volumes()?
        .iter()
        .map(|v| {
            let flux = v.flux.iter().map(|f| trilinear(f, u)).collect();
            (trilinear(&v.fluence, u), flux)
        })
        .collect();
    let run_id = &folder.sidecar.run_id;
    if args.json {
        let v: Vec<Value> = out
            .iter()
            .map(|(e, d)| {
                json!({
                    "fluence": e.to_array(),
                    "flux": d.iter().map(|x| x.to_array()).collect::<Vec<_>>(),
                })
            })
            .collect();
        println!(
            "{}",
            serde_json::to_string_pretty(
                &json!({ "at": args.at.to_array(), "run_id": run_id, "lights": v })
            )?
        );
    } else {
        println!("at            {}", fmt_vec(args.at));
        println!("run           {run_id}");
        for (i, (e, d)) in out.iter().enumerate() {
            println!("light {i}");
            println!("  fluence     {} W/unit^2 (R, G, B)", fmt_vec(*e));
            for (c, dc) in d.iter().enumerate() {
                let label = if d.len() == 1 {
                    "flux".to_string()
                } else {
                    format!("flux {}", ["R", "G", "B"][c])
                };
                println!("  {label:<11} {}", fmt_vec(*dc));
            }
        }
    }
    Ok(())
}
