//! `eikon slice`: a false-colour PNG of one plane of a built field.

use crate::output::{viridis, write_atomic};
use anyhow::{bail, Context, Result};
use clap::ValueEnum;
use eikon_grid::Scene;
use std::path::PathBuf;

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Axis {
    X,
    Y,
    Z,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum FieldArg {
    /// Smoothed refractive index.
    N,
    /// Magnitude of the index gradient.
    Gradient,
    /// Boundary indicator (discrete Dirac delta).
    Boundary,
    /// Mean RGB extinction.
    Extinction,
}

/// Arguments of `eikon slice`.
#[derive(clap::Args)]
pub struct Args {
    /// Scene file (TOML).
    scene: PathBuf,
    /// Axis normal to the slice.
    #[arg(long, value_enum)]
    axis: Axis,
    /// Position of the slice along the axis, as a fraction of the bounds (0..1).
    #[arg(long)]
    at: f64,
    /// Output PNG.
    #[arg(short, long)]
    output: PathBuf,
    /// Which field to show.
    #[arg(long, value_enum, default_value = "n")]
    field: FieldArg,
    /// Index channel (0, 1, 2 = R, G, B) for a dispersive scene.
    #[arg(long, default_value_t = 0)]
    channel: usize,
    /// Enlarge each voxel to k x k pixels.
    #[arg(long, default_value_t = 4)]
    scale: usize,
}

/// Run `eikon slice`.
pub fn run(args: Args) -> Result<()> {
    if !(0.0..=1.0).contains(&args.at) {
        bail!("--at: must be a fraction in [0, 1], got {}", args.at);
    }
    if !(1..=64).contains(&args.scale) {
        bail!("--scale: must lie in 1..=64, got {}", args.scale);
    }
    if args.channel > 2 {
        bail!("--channel: must be 0, 1 or 2, got {}", args.channel);
    }
    if args.output.extension().and_then(|e| e.to_str()) != Some("png") {
        bail!("{}: the output must be a .png file", args.output.display());
    }
    let scene = Scene::load(&args.scene)?;
    let m = crate::output::build_medium(&scene)?;
    let [nx, ny, nz] = m.geometry.dims;
    let ch = args.channel.min(m.channels() - 1);
    let value = |i: usize, j: usize, k: usize| -> f32 {
        match args.field {
            FieldArg::N => m.index[ch][[i, j, k, 0]],
            FieldArg::Gradient => m.gradient_at(ch, i, j, k).length() as f32,
            FieldArg::Boundary => m.boundary[[i, j, k]],
            FieldArg::Extinction => (0..3).map(|c| m.extinction[[i, j, k, c]]).sum::<f32>() / 3.0,
        }
    };
    let pick = |n: usize| ((args.at * n as f64).floor() as usize).min(n - 1);
    // Image axes: (horizontal, vertical) = (y, z), (x, z), (x, y); vertical
    // grows upward in the picture.
    let (w, h) = match args.axis {
        Axis::X => (ny, nz),
        Axis::Y => (nx, nz),
        Axis::Z => (nx, ny),
    };
    let at = |u: usize, v: usize| -> f32 {
        match args.axis {
            Axis::X => value(pick(nx), u, v),
            Axis::Y => value(u, pick(ny), v),
            Axis::Z => value(u, v, pick(nz)),
        }
    };
    let mut vals = Vec::with_capacity(w * h);
    for v in (0..h).rev() {
        for u in 0..w {
            vals.push(at(u, v));
        }
    }
    let (lo, hi) = vals
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });
    let span = if hi > lo { (hi - lo) as f64 } else { 1.0 };
    let s = args.scale;
    let (pw, ph) = (w * s, h * s);
    let mut rgb = vec![0u8; pw * ph * 3];
    for y in 0..ph {
        for x in 0..pw {
            let c = viridis((vals[(y / s) * w + x / s] - lo) as f64 / span);
            rgb[(y * pw + x) * 3..][..3].copy_from_slice(&c);
        }
    }
    write_atomic(&args.output, |out| {
        let mut enc = png::Encoder::new(out, pw as u32, ph as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut wr = enc.write_header().context("PNG header")?;
        wr.write_image_data(&rgb).context("PNG data")?;
        wr.finish().context("PNG finish")?;
        Ok(())
    })?;
    eprintln!(
        "wrote {} ({pw} x {ph} px): range {lo:.5} .. {hi:.5} mapped to viridis dark .. bright",
        args.output.display()
    );
    Ok(())
}
