//! `eikon probe`: the light at one point of simulated light volumes.

use crate::output::{fmt_vec, parse_vec3};
use crate::simulate::SIDECAR;
use anyhow::{bail, Context, Result};
use glam::DVec3;
use ndarray::{ArrayD, IxDyn};
use ndarray_npy::read_npy;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};

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

fn vec3(v: &Value, what: &str, sidecar: &Path) -> Result<DVec3> {
    let a: Vec<f64> = serde_json::from_value(v.clone())
        .with_context(|| format!("{}: {what} is not a list of numbers", sidecar.display()))?;
    if a.len() != 3 {
        bail!("{}: {what} needs 3 numbers", sidecar.display());
    }
    Ok(DVec3::new(a[0], a[1], a[2]))
}

/// Trilinear interpolation (cell-centre convention) of the last-axis
/// vector of `a` (leading `lead` indices fixed) at continuous voxel `u`.
fn trilinear(a: &ArrayD<f32>, lead: &[usize], dims: [usize; 3], u: DVec3) -> DVec3 {
    let hi = DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64) - 1.0;
    let u = u.clamp(DVec3::ZERO, hi);
    let i0 = [0, 1, 2].map(|k| (u[k] as usize).min(dims[k].saturating_sub(2)));
    let f = [0, 1, 2].map(|k| u[k] - i0[k] as f64);
    let mut out = DVec3::ZERO;
    for corner in 0..8 {
        let d = [corner & 1, (corner >> 1) & 1, (corner >> 2) & 1];
        let mut w = 1.0;
        let mut idx: Vec<usize> = lead.to_vec();
        for k in 0..3 {
            idx.push((i0[k] + d[k]).min(dims[k] - 1));
            w *= if d[k] == 1 { f[k] } else { 1.0 - f[k] };
        }
        for c in 0..3 {
            idx.push(c);
            out[c] += w * a[IxDyn(&idx)] as f64;
            idx.pop();
        }
    }
    out
}

/// Run `eikon probe`.
pub fn run(args: Args) -> Result<()> {
    let sidecar = args.volumes.join(SIDECAR);
    let text = std::fs::read_to_string(&sidecar).with_context(|| {
        format!(
            "{}: cannot read the light-volume description (is {} an `eikon simulate` output?)",
            sidecar.display(),
            args.volumes.display()
        )
    })?;
    let meta: Value = serde_json::from_str(&text)
        .with_context(|| format!("{}: not valid JSON", sidecar.display()))?;
    if meta["format"] != "eikon-light-volumes" {
        bail!(
            "{}: format: not an eikon light-volume description",
            sidecar.display()
        );
    }
    let dims: [usize; 3] = serde_json::from_value(meta["grid"]["dims"].clone())
        .with_context(|| format!("{}: grid.dims", sidecar.display()))?;
    let min = vec3(&meta["grid"]["min"], "grid.min", &sidecar)?;
    let max = vec3(&meta["grid"]["max"], "grid.max", &sidecar)?;
    let spacing = vec3(&meta["grid"]["spacing"], "grid.spacing", &sidecar)?;
    if !(args.at.cmpge(min).all() && args.at.cmple(max).all()) {
        bail!(
            "--at: {} lies outside the volume {} .. {}",
            fmt_vec(args.at),
            fmt_vec(min),
            fmt_vec(max)
        );
    }
    let u = (args.at - min) / spacing - 0.5;
    let lights = meta["lights"]
        .as_array()
        .with_context(|| format!("{}: lights", sidecar.display()))?;
    let mut out = Vec::new();
    for (i, l) in lights.iter().enumerate() {
        let file = |key: &str| -> Result<ArrayD<f32>> {
            let name = l[key]
                .as_str()
                .with_context(|| format!("{}: lights[{i}].{key}", sidecar.display()))?;
            let path = args.volumes.join(name);
            let a: ArrayD<f32> =
                read_npy(&path).with_context(|| format!("{}: cannot read", path.display()))?;
            Ok(a)
        };
        let irr = file("fluence_file")?;
        let dir = Some(file("flux_file")?);
        let shape_ok = |a: &ArrayD<f32>, lead: usize| {
            a.ndim() == 4 + lead && a.shape()[lead..lead + 3] == dims && a.shape()[lead + 3] == 3
        };
        if !shape_ok(&irr, 0)
            || dir
                .as_ref()
                .is_some_and(|d| !(shape_ok(d, 0) || shape_ok(d, 1)))
        {
            bail!(
                "{}: light {i}: arrays do not match grid.dims {dims:?}",
                args.volumes.display()
            );
        }
        let e = trilinear(&irr, &[], dims, u);
        let directions: Vec<DVec3> = match &dir {
            None => Vec::new(),
            Some(d) if d.ndim() == 4 => vec![trilinear(d, &[], dims, u)],
            Some(d) => (0..d.shape()[0])
                .map(|c| trilinear(d, &[c], dims, u))
                .collect(),
        };
        out.push((e, directions));
    }
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
            serde_json::to_string_pretty(&json!({ "at": args.at.to_array(), "lights": v }))?
        );
    } else {
        println!("at            {}", fmt_vec(args.at));
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
