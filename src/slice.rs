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
    /// The exact interfaces (`[grid] interfaces = "sharp"`): each region's
    /// own index, sampled at every pixel, with the surfaces between
    /// regions drawn in white.
    Interfaces,
}

/// Arguments of `eikon slice`.
#[derive(clap::Args, Clone)]
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
    if args.field == FieldArg::Interfaces {
        return interfaces(&args, &scene);
    }
    let m = crate::output::build_medium(&scene)?;
    let [nx, ny, nz] = m.geometry.dims;
    let ch = args.channel.min(m.channels() - 1);
    let value = |i: usize, j: usize, k: usize| -> f32 {
        match args.field {
            FieldArg::N => m.index[ch][[i, j, k, 0]],
            FieldArg::Gradient => m.gradient_at(ch, i, j, k).length() as f32,
            FieldArg::Boundary => m.boundary[[i, j, k]],
            FieldArg::Extinction => (0..3).map(|c| m.extinction[[i, j, k, c]]).sum::<f32>() / 3.0,
            FieldArg::Interfaces => unreachable!("drawn from the regions"),
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
    write_png(&args, &vals, w, h)
}

/// Write `vals` (`w` x `h`, top row first) as a viridis PNG, each value
/// `args.scale` pixels square; NaN is drawn white.
fn write_png(args: &Args, vals: &[f32], w: usize, h: usize) -> Result<()> {
    let (lo, hi) = vals
        .iter()
        .filter(|x| !x.is_nan())
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });
    let span = if hi > lo { (hi - lo) as f64 } else { 1.0 };
    let s = args.scale;
    let (pw, ph) = (w * s, h * s);
    let mut rgb = vec![0u8; pw * ph * 3];
    for y in 0..ph {
        for x in 0..pw {
            let v = vals[(y / s) * w + x / s];
            let c = if v.is_nan() {
                [255, 255, 255]
            } else {
                viridis((v - lo) as f64 / span)
            };
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

/// `--field interfaces`: the regions of the scene's exact surfaces on the
/// slice plane, at `args.scale` samples per voxel.
fn interfaces(args: &Args, scene: &Scene) -> Result<()> {
    let g = &scene.grid.geometry;
    let regions = eikon_grid::Regions::new(scene);
    let s = args.scale;
    let [nx, ny, nz] = g.dims.map(|n| n * s);
    let (w, h) = match args.axis {
        Axis::X => (ny, nz),
        Axis::Y => (nx, nz),
        Axis::Z => (nx, ny),
    };
    let size = g.max - g.min;
    let point = |u: usize, v: usize| -> glam::DVec3 {
        let f = |i: usize, n: usize| (i as f64 + 0.5) / n as f64;
        let t = match args.axis {
            Axis::X => glam::DVec3::new(args.at, f(u, w), f(v, h)),
            Axis::Y => glam::DVec3::new(f(u, w), args.at, f(v, h)),
            Axis::Z => glam::DVec3::new(f(u, w), f(v, h), args.at),
        };
        g.min + size * t
    };
    let owner: Vec<_> = (0..w * h)
        .map(|i| regions.at(point(i % w, i / w)))
        .collect();
    let ch = args.channel.min(scene.channels() - 1);
    let mut vals = Vec::with_capacity(w * h);
    for v in (0..h).rev() {
        for u in 0..w {
            let r = owner[v * w + u];
            let edge = (u + 1 < w && owner[v * w + u + 1] != r)
                || (v + 1 < h && owner[(v + 1) * w + u] != r);
            vals.push(if edge {
                f32::NAN
            } else {
                regions.index(r, point(u, v), ch).0 as f32
            });
        }
    }
    write_png(
        &Args {
            scale: 1,
            ..args.clone()
        },
        &vals,
        w,
        h,
    )
}
