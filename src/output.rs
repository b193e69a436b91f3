//! Shared CLI plumbing: argument parsing, atomic writes, colour maps.

use anyhow::{bail, Context, Result};
use eikon_wavefront::staging::Staging;
use glam::DVec3;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Parse `x,y,z` into a vector (clap value parser).
pub fn parse_vec3(s: &str) -> std::result::Result<DVec3, String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return Err(format!(
            "expected three comma-separated numbers x,y,z, got `{s}`"
        ));
    }
    let mut v = [0.0; 3];
    for (slot, p) in v.iter_mut().zip(&parts) {
        *slot = p
            .parse::<f64>()
            .map_err(|_| format!("`{p}` is not a number (in `{s}`)"))?;
        if !slot.is_finite() {
            return Err(format!("`{p}` is not finite (in `{s}`)"));
        }
    }
    Ok(DVec3::from_array(v))
}

/// Write a file atomically: the bytes go to a temporary file beside `path`,
/// which is renamed into place only once complete, so a failure never
/// leaves a half-written output.
pub fn write_atomic(path: &Path, write: impl FnOnce(&mut dyn Write) -> Result<()>) -> Result<()> {
    let mut staging = Staging::new();
    // The writer's own error (with its context) is the one reported.
    let mut failure = None;
    let staged = staging.add(path, |w| {
        write(w).map_err(|e| {
            let m = format!("{e:#}");
            failure = Some(e);
            m
        })
    });
    if let Some(e) = failure {
        return Err(e);
    }
    staged?;
    Ok(staging.commit()?)
}

/// Write several outputs of one run (images in several formats): each to a
/// temporary beside it, all renamed into place together only once every
/// one is complete, so a failed or killed run never leaves one output new
/// and its companion old or half-written.
pub fn write_all_atomic(outputs: &[(PathBuf, Vec<u8>)]) -> Result<()> {
    let mut staging = Staging::new();
    for (path, bytes) in outputs {
        staging.add(path, |w| w.write_all(bytes))?;
    }
    Ok(staging.commit()?)
}

/// Viridis colour map at `t` in [0, 1] (piecewise-linear through 9 stops of
/// the matplotlib table).
pub fn viridis(t: f64) -> [u8; 3] {
    const STOPS: [[f64; 3]; 9] = [
        [68.0, 1.0, 84.0],
        [71.0, 44.0, 122.0],
        [59.0, 81.0, 139.0],
        [44.0, 113.0, 142.0],
        [33.0, 144.0, 141.0],
        [39.0, 173.0, 129.0],
        [92.0, 200.0, 99.0],
        [170.0, 220.0, 50.0],
        [253.0, 231.0, 37.0],
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let x = t * (STOPS.len() - 1) as f64;
    let i = (x.floor() as usize).min(STOPS.len() - 2);
    let f = x - i as f64;
    let mut out = [0u8; 3];
    for (c, o) in out.iter_mut().enumerate() {
        *o = (STOPS[i][c] * (1.0 - f) + STOPS[i + 1][c] * f).round() as u8;
    }
    out
}

/// Format a vector for people.
pub fn fmt_vec(v: DVec3) -> String {
    format!("({:.6}, {:.6}, {:.6})", v.x, v.y, v.z)
}

/// Copy `from` to `to` through a temporary file beside `to`.
pub fn copy_atomic(from: &Path, to: &Path) -> Result<()> {
    let bytes = std::fs::read(from).with_context(|| format!("{}: cannot read", from.display()))?;
    write_atomic(to, |w| {
        w.write_all(&bytes)
            .with_context(|| format!("{}: write failed", to.display()))
    })
}

/// Build a scene's medium with a progress bar on stderr (drawn only when
/// stderr is a terminal).
pub fn build_medium(scene: &eikon_grid::Scene) -> Result<eikon_grid::Medium> {
    build_with_bar(scene, eikon_grid::Medium::build_within)
}

/// [`build_medium`] of the surfaces alone
/// ([`eikon_grid::Medium::build_surfaces_within`]): what a light simulation
/// with sharp interfaces reads on the CPU.
pub fn build_surfaces(scene: &eikon_grid::Scene) -> Result<eikon_grid::Medium> {
    build_with_bar(scene, eikon_grid::Medium::build_surfaces_within)
}

fn build_with_bar(
    scene: &eikon_grid::Scene,
    build: impl FnOnce(
        &eikon_grid::Scene,
        u128,
        eikon_grid::BuildProgress,
    ) -> eikon_grid::Result<eikon_grid::Medium>,
) -> Result<eikon_grid::Medium> {
    let bar = indicatif::ProgressBar::new(1);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg:>20} [{bar:40}] {pos}/{len} ({elapsed})")
            .expect("valid template")
            .progress_chars("=> "),
    );
    let limit = crate::grid::memory_limit();
    let medium = build(scene, limit, &|stage, done, total| {
        bar.set_message(stage);
        bar.set_length(total);
        bar.set_position(done);
    });
    bar.finish_and_clear();
    Ok(medium?)
}

/// A PNG's size and RGB8 pixels (RGBA and grey are converted).
pub fn read_rgb8(path: &Path) -> Result<(u32, u32, Vec<u8>)> {
    let file =
        std::fs::File::open(path).with_context(|| format!("{}: cannot open", path.display()))?;
    let mut dec = png::Decoder::new(std::io::BufReader::new(file));
    dec.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut reader = dec
        .read_info()
        .with_context(|| format!("{}: not a PNG", path.display()))?;
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader
        .next_frame(&mut buf)
        .with_context(|| format!("{}: corrupt PNG", path.display()))?;
    buf.truncate(info.buffer_size());
    let (w, h) = (info.width, info.height);
    let rgb = match info.color_type {
        png::ColorType::Rgb => buf,
        png::ColorType::Rgba => buf
            .chunks_exact(4)
            .flat_map(|p| [p[0], p[1], p[2]])
            .collect(),
        png::ColorType::Grayscale => buf.iter().flat_map(|&g| [g, g, g]).collect(),
        png::ColorType::GrayscaleAlpha => buf
            .chunks_exact(2)
            .flat_map(|p| [p[0], p[0], p[0]])
            .collect(),
        other => bail!("{}: unexpected PNG colour type {other:?}", path.display()),
    };
    Ok((w, h, rgb))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vec3_parsing_rejects_bad_input() {
        assert_eq!(parse_vec3("1, -2,3.5").unwrap(), DVec3::new(1.0, -2.0, 3.5));
        assert!(parse_vec3("1,2").is_err());
        assert!(parse_vec3("1,2,x").is_err());
        assert!(parse_vec3("1,2,nan").is_err());
    }

    #[test]
    fn viridis_ends() {
        assert_eq!(viridis(0.0), [68, 1, 84]);
        assert_eq!(viridis(1.0), [253, 231, 37]);
    }
}
