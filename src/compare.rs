//! `eikon compare`: one scene with a mesh-bounded medium rendered by every
//! method, side by side, with each method's relative L1 difference from a
//! reference and its time.

use crate::label;
use crate::output::{build_medium, write_atomic};
use crate::render::{self, check_outputs, write_images, ExactOptions, Overrides, RenderMethod};
use crate::simulate;
use anyhow::{bail, Context, Result};
use eikon_optics::image::luminance;
use eikon_optics::{Exposure, Image, ToneMap};
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
    /// Methods to render, in order [default: eikonal, walter, holzschuch,
    /// straight, and wyman, the image-space method, when the eikonal method
    /// runs on a GPU and the scene is one wyman renders].
    #[arg(long, value_enum, value_delimiter = ',')]
    methods: Option<Vec<RenderMethod>>,
    /// The method the others are measured against.
    #[arg(long, value_enum, default_value = "holzschuch")]
    reference: RenderMethod,
    #[command(flatten)]
    exact: ExactOptions,
    #[command(flatten)]
    wyman: crate::wyman::WymanOptions,
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

/// Font scale of the labels of `images`: 2 where every label fits its
/// panel at twice the font size (with its margins), else 1.
fn label_scale(images: &[&Image], labels: &[String]) -> u32 {
    let fits = images
        .iter()
        .zip(labels)
        .all(|(im, text)| label::text_width(text, 2) + 8 <= im.width);
    if fits && !labels.is_empty() {
        2
    } else {
        1
    }
}

/// Height of the black strip above the panels that holds their labels:
/// the text with two font pixels of margin above and below.
fn label_strip(scale: u32) -> u32 {
    label::text_height(scale) + 4 * scale
}

/// The images side by side, separated by `gap` black columns, under a
/// black strip with each one's label (`labels[i]` over `images[i]`) in
/// `white`: a radiance that the sheet's tone curve maps to white. A label
/// wider than its panel is cut off at the panel's edge.
fn contact_sheet(images: &[&Image], labels: &[String], gap: u32, white: f32) -> Image {
    let scale = label_scale(images, labels);
    let top = label_strip(scale);
    let h = images.iter().map(|i| i.height).max().unwrap_or(0) + top;
    let w =
        images.iter().map(|i| i.width).sum::<u32>() + gap * (images.len() as u32).saturating_sub(1);
    let mut sheet = Image::new(w, h);
    let mut x0 = 0;
    for (k, im) in images.iter().enumerate() {
        for y in 0..im.height {
            for x in 0..im.width {
                if let (Some(p), Some(q)) = (im.pixel(x, y), sheet.pixel_mut(x0 + x, top + y)) {
                    *q = p;
                }
            }
        }
        if let Some(text) = labels.get(k) {
            let clip = label::Rect {
                x0,
                y0: 0,
                x1: x0 + im.width,
                y1: top,
            };
            label::draw_text(text, x0 + 2 * scale, 2 * scale, scale, clip, |x, y| {
                if let Some(q) = sheet.pixel_mut(x, y) {
                    *q = [white; 3];
                }
            });
        }
        x0 += im.width + gap;
    }
    sheet
}

/// The label of one panel: the method, and its relative L1 difference from
/// the reference (`None`: this is the reference).
fn panel_label(method: &str, l1: Option<f64>) -> String {
    match l1 {
        None => format!("{method}  reference"),
        Some(l1) => format!("{method}  L1 {l1:.3}"),
    }
}

/// Run `eikon compare`.
pub fn run(args: Args) -> Result<()> {
    let asked = args.methods.is_some();
    let mut methods = args.methods.clone().unwrap_or_else(|| {
        vec![
            RenderMethod::Eikonal,
            RenderMethod::Walter,
            RenderMethod::Holzschuch,
            RenderMethod::Straight,
        ]
    });
    if methods.is_empty() {
        bail!("--methods: name at least one method");
    }
    methods.dedup();
    if !methods.contains(&args.reference) {
        bail!(
            "--reference: {} is not among --methods",
            args.reference.name()
        );
    }
    let scene = args.overrides.grid.load(&args.scene)?;
    // Refuse a scene the exact methods cannot render before any work.
    crate::exact::mesh_medium(&scene)?;
    crate::exact::mesh_lights(&scene)?;
    if args.output.exists() && !args.output.is_dir() {
        bail!("{}: exists and is not a directory", args.output.display());
    }
    let backend = if methods.contains(&RenderMethod::Eikonal) {
        args.overrides.backend.select(args.json)?
    } else {
        crate::backend::Backend::Cpu
    };
    if !asked && backend.name() == "gpu" {
        // The image-space method's row where a GPU renders anyway.
        match crate::wyman::check(&scene) {
            Ok(()) => methods.push(RenderMethod::Wyman),
            Err(e) => eprintln!("compare: no wyman row: {e:#}"),
        }
    }
    let files: Vec<PathBuf> = methods
        .iter()
        .flat_map(|m| ["exr", "png"].map(|e| args.output.join(format!("{}.{e}", m.name()))))
        .collect();
    check_outputs(&files)?;
    let camera = render::camera(&scene, &args.overrides)?;
    let seed = args.overrides.seed.unwrap_or(scene.render.seed);

    let wyman = if methods.contains(&RenderMethod::Wyman) {
        if asked {
            crate::wyman::check(&scene)?;
        }
        Some(crate::wyman::device()?)
    } else {
        None
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
        } else if let (RenderMethod::Wyman, Some(gpu)) = (m, &wyman) {
            crate::wyman::image(gpu, &scene, &args.overrides, &args.wyman)?.0
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
        let paths = ["exr", "png"].map(|e| args.output.join(format!("{}.{e}", m.name())));
        write_images(&paths, image, &tone)?;
        let lum: Vec<f64> = image.data.iter().map(|&p| luminance(p)).collect();
        rows.push(json!({
            "method": m.name(),
            "seconds": seconds,
            "relative_l1": relative_l1(image, reference),
            "mean_luminance": lum.iter().sum::<f64>() / lum.len().max(1) as f64,
            "max_luminance": lum.iter().copied().fold(0.0, f64::max),
        }));
    }
    let labels: Vec<String> = results
        .iter()
        .map(|(m, image, _)| {
            let l1 = (*m != args.reference).then(|| relative_l1(image, reference));
            panel_label(m.name(), l1)
        })
        .collect();
    // Radiance that the tone curve maps to white: s L / (1 + s L) rounds
    // to 255 from s L = 221 on.
    let white = if scale > 0.0 && scale.is_finite() {
        (1e4 / scale).min(f64::from(f32::MAX) / 4.0) as f32
    } else {
        1e4
    };
    let sheet = contact_sheet(
        &results.iter().map(|r| &r.1).collect::<Vec<_>>(),
        &labels,
        4,
        white,
    );
    write_images(&[args.output.join("contact.png")], &sheet, &tone)?;
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

#[cfg(test)]
mod tests {
    use super::*;

    fn flat(w: u32, h: u32, v: f32) -> Image {
        Image::from_data(w, h, vec![[v; 3]; (w * h) as usize]).unwrap()
    }

    #[test]
    fn panels_sit_under_a_strip_with_their_labels() {
        let (a, b) = (flat(40, 10, 0.5), flat(30, 12, 0.25));
        let labels = ["walter  L1 0.044".to_string(), "reference".to_string()];
        let white = 1e4;
        let sheet = contact_sheet(&[&a, &b], &labels, 4, white);
        let top = label_strip(1);
        assert_eq!(top, 11);
        assert_eq!((sheet.width, sheet.height), (40 + 4 + 30, 12 + top));
        // The panels, moved down by the strip.
        assert_eq!(sheet.pixel(0, top), Some([0.5; 3]));
        assert_eq!(sheet.pixel(39, top + 9), Some([0.5; 3]));
        assert_eq!(sheet.pixel(44, top), Some([0.25; 3]));
        assert_eq!(sheet.pixel(73, top + 11), Some([0.25; 3]));
        // The gap and the strip are black but for the letters, in white.
        assert_eq!(sheet.pixel(41, top + 3), Some([0.0; 3]));
        let lit = |x0: u32, x1: u32| {
            (0..top)
                .flat_map(|y| (x0..x1).map(move |x| (x, y)))
                .filter(|&(x, y)| sheet.pixel(x, y) == Some([white; 3]))
                .count()
        };
        assert!(lit(0, 40) > 20 && lit(44, 74) > 20);
        assert_eq!(lit(40, 44), 0, "a label spilled into the gap");
        let others = (0..top)
            .flat_map(|y| (0..sheet.width).map(move |x| (x, y)))
            .filter(
                |&(x, y)| !matches!(sheet.pixel(x, y), Some(p) if p == [0.0; 3] || p == [white; 3]),
            )
            .count();
        assert_eq!(others, 0);
        // The first letter, 'w', at (2, 2): its first column is lit from
        // the third font row down (x-height letters start there).
        assert_eq!(sheet.pixel(2, 4), Some([white; 3]));
        assert_eq!(sheet.pixel(2, 3), Some([0.0; 3]));
        // The tone curve maps the label white to 8-bit white.
        let tone = ToneMap {
            exposure: Exposure::Fixed(0.0),
            ..ToneMap::default()
        };
        assert_eq!(tone.map_pixel([white; 3], 1.0), [255; 3]);
    }

    #[test]
    fn labels_are_twice_the_size_where_they_fit() {
        let text = "eikonal  L1 0.123".to_string();
        // 17 characters: 101 font pixels, 202 at 2x, plus 2x margins.
        assert_eq!(label::text_width(&text, 2), 202);
        let a = flat(210, 20, 0.1);
        let sheet = contact_sheet(&[&a], std::slice::from_ref(&text), 4, 1.0);
        assert_eq!(label_strip(2), 22);
        assert_eq!(sheet.height, 20 + label_strip(2));
        let narrow = flat(209, 20, 0.1);
        let sheet = contact_sheet(&[&a, &narrow], &[text.clone(), text], 4, 1.0);
        assert_eq!(sheet.height, 20 + label_strip(1));
    }

    #[test]
    fn labels_name_the_method_and_its_difference() {
        assert_eq!(panel_label("walter", Some(0.04412)), "walter  L1 0.044");
        assert_eq!(panel_label("holzschuch", None), "holzschuch  reference");
        assert_eq!(
            panel_label("straight", Some(f64::INFINITY)),
            "straight  L1 inf"
        );
    }
}
