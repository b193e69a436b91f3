//! `eikon compare`: one scene with a mesh-bounded medium rendered by every
//! method, side by side, with each method's relative L1 difference from a
//! reference and its time.

use crate::output::{build_medium, write_atomic};
use crate::render::{self, check_outputs, write_image, ExactOptions, Overrides, RenderMethod};
use crate::simulate;
use anyhow::{bail, Context, Result};
use eikon_grid::Scene;
use eikon_view::image::luminance;
use eikon_view::{Exposure, Image, ToneMap};
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `eikon compare`.
#[derive(clap::Args)]
pub struct Args {
    /// Scene file (TOML) whose one object is a mesh.
    scene: PathBuf,
    /// Output directory: one EXR and PNG per method, `contact.png` (the
    /// methods side by side, in the order given, at one exposure) and
    /// `compare.json`; the eikonal method's light volumes go to `light/`.
    #[arg(short, long)]
    output: PathBuf,
    /// Methods to render, in order.
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "eikonal,walter,holzschuch,straight"
    )]
    methods: Vec<RenderMethod>,
    /// The method the others are measured against.
    #[arg(long, value_enum, default_value = "holzschuch")]
    reference: RenderMethod,
    #[command(flatten)]
    exact: ExactOptions,
    #[command(flatten)]
    overrides: Overrides,
    /// Print the table as JSON.
    #[arg(long)]
    json: bool,
}

/// `sum |a - b| / sum |b|` over every pixel and channel: the relative L1
/// difference of `a` from the reference `b`.
pub fn relative_l1(a: &Image, b: &Image) -> f64 {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (p, q) in a.data.iter().zip(&b.data) {
        for c in 0..3 {
            num += (f64::from(p[c]) - f64::from(q[c])).abs();
            den += f64::from(q[c]).abs();
        }
    }
    if den > 0.0 {
        num / den
    } else if num > 0.0 {
        f64::INFINITY
    } else {
        0.0
    }
}

/// The images side by side, separated by `gap` black columns.
fn contact_sheet(images: &[&Image], gap: u32) -> Image {
    let h = images.iter().map(|i| i.height).max().unwrap_or(0);
    let w =
        images.iter().map(|i| i.width).sum::<u32>() + gap * (images.len() as u32).saturating_sub(1);
    let mut sheet = Image::new(w, h);
    let mut x0 = 0;
    for im in images {
        for y in 0..im.height {
            for x in 0..im.width {
                if let (Some(p), Some(q)) = (im.pixel(x, y), sheet.pixel_mut(x0 + x, y)) {
                    *q = p;
                }
            }
        }
        x0 += im.width + gap;
    }
    sheet
}

/// Run `eikon compare`.
pub fn run(args: Args) -> Result<()> {
    if args.methods.is_empty() {
        bail!("--methods: name at least one method");
    }
    let mut methods = args.methods.clone();
    methods.dedup();
    if !methods.contains(&args.reference) {
        bail!(
            "--reference: {} is not among --methods",
            args.reference.name()
        );
    }
    let scene = Scene::load(&args.scene)?;
    // Refuse a scene the exact methods cannot render before any work.
    crate::exact::mesh_medium(&scene)?;
    crate::exact::mesh_lights(&scene)?;
    if args.output.exists() && !args.output.is_dir() {
        bail!("{}: exists and is not a directory", args.output.display());
    }
    let files: Vec<PathBuf> = methods
        .iter()
        .flat_map(|m| ["exr", "png"].map(|e| args.output.join(format!("{}.{e}", m.name()))))
        .collect();
    check_outputs(&files)?;
    let camera = render::camera(&scene, &args.overrides)?;
    let seed = args.overrides.seed.unwrap_or(scene.render.seed);

    let backend = if methods.contains(&RenderMethod::Eikonal) {
        args.overrides.backend.select(args.json)?
    } else {
        crate::backend::Backend::Cpu
    };
    let mut results: Vec<(RenderMethod, Image, f64)> = Vec::new();
    for &m in &methods {
        eprintln!("{}:", m.name());
        let started = Instant::now();
        let image = if m == RenderMethod::Eikonal {
            let medium = build_medium(&scene)?;
            let sim = simulate::Args::defaults(args.scene.clone(), args.output.join("light"));
            let volumes = simulate::simulate_quiet(&sim, &scene, &medium, &backend)?;
            render::render_image(&scene, &medium, &volumes, &args.overrides, &backend)?.0
        } else {
            let method = crate::exact::method(m.name(), args.exact.scatter_samples)?;
            crate::exact::render(&scene, &camera, method, args.exact.guaranteed, seed)?.0
        };
        results.push((m, image, started.elapsed().as_secs_f64()));
    }

    // One exposure for all: the reference's.
    let reference = &results
        .iter()
        .find(|r| r.0 == args.reference)
        .expect("checked above")
        .1;
    let scale = render::tone(&scene, &args.overrides).scale(reference);
    let tone = ToneMap {
        exposure: Exposure::Fixed(scale.log2()),
        ..ToneMap::default()
    };
    std::fs::create_dir_all(&args.output).with_context(|| {
        format!(
            "{}: cannot create the output directory",
            args.output.display()
        )
    })?;
    let mut rows = Vec::new();
    for (m, image, seconds) in &results {
        for e in ["exr", "png"] {
            write_image(&args.output.join(format!("{}.{e}", m.name())), image, &tone)?;
        }
        let lum: Vec<f64> = image.data.iter().map(|&p| luminance(p)).collect();
        rows.push(json!({
            "method": m.name(),
            "seconds": seconds,
            "relative_l1": relative_l1(image, reference),
            "mean_luminance": lum.iter().sum::<f64>() / lum.len().max(1) as f64,
            "max_luminance": lum.iter().copied().fold(0.0, f64::max),
        }));
    }
    let sheet = contact_sheet(&results.iter().map(|r| &r.1).collect::<Vec<_>>(), 4);
    write_image(&args.output.join("contact.png"), &sheet, &tone)?;
    let table = json!({
        "scene": args.scene.display().to_string(),
        "reference": args.reference.name(),
        "width": camera.width(),
        "height": camera.height(),
        "methods": rows,
        "contact_sheet": args.output.join("contact.png").display().to_string(),
    });
    let path = args.output.join("compare.json");
    write_atomic(&path, |w| {
        serde_json::to_writer_pretty(&mut *w, &table)?;
        w.write_all(b"\n")?;
        Ok(())
    })?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&table)?);
    } else {
        println!(
            "{} ({} x {}), against {}:",
            args.scene.display(),
            camera.width(),
            camera.height(),
            args.reference.name()
        );
        println!("  {:<12} {:>10} {:>12}", "method", "seconds", "relative L1");
        for (m, image, seconds) in &results {
            let l1 = if *m == args.reference {
                "reference".to_string()
            } else {
                format!("{:.4}", relative_l1(image, reference))
            };
            println!("  {:<12} {:>10.3} {:>12}", m.name(), seconds, l1);
        }
        println!(
            "wrote {} (left to right: {})",
            args.output.join("contact.png").display(),
            results
                .iter()
                .map(|r| r.0.name())
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    Ok(())
}
