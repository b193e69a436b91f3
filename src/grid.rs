//! `--resolution`, `--smoothing` and `--preview`: the command line's say
//! over a scene's `[grid]`, shared by every command that builds a medium.

use anyhow::Result;
use eikon_grid::field::format_bytes;
use eikon_grid::{GridOverride, Medium, Scene};
use std::path::Path;

/// The most voxels along the longest axis `--resolution` accepts (the
/// memory check refuses what will not fit long before this).
pub const MAX_RESOLUTION: u64 = 4096;

/// Voxels along the longest axis with `--preview` (unless the scene has
/// fewer, or `--resolution` says otherwise).
pub const PREVIEW_RESOLUTION: u64 = 48;

/// The image width `--preview` renders at most, in pixels.
pub const PREVIEW_WIDTH: u32 = 320;

fn parse_smoothing(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|e| format!("{e}"))?;
    if (0.0..=8.0).contains(&v) {
        Ok(v)
    } else {
        Err(format!("sigma in voxels must lie in [0, 8], got {v}"))
    }
}

/// Grid flags of `simulate`, `render`, `run`, `export` and `bench`.
#[derive(clap::Args, Clone, Copy, Debug, Default)]
pub struct GridFlags {
    /// Voxels along the grid's longest axis, instead of the scene's
    /// `[grid] resolution` (the other axes keep their proportions). Render
    /// and export a simulation with the resolution it was simulated at.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=MAX_RESOLUTION))]
    pub resolution: Option<u64>,
    /// Gaussian smoothing of the index before the gradient, sigma in
    /// voxels, instead of the scene's `[grid] smoothing`.
    #[arg(long, value_parser = parse_smoothing)]
    pub smoothing: Option<f64>,
    /// A fast first look: at most 48 voxels along the longest axis and, for
    /// images, at most 320 pixels wide with one sample per pixel.
    #[arg(long)]
    pub preview: bool,
}

impl GridFlags {
    /// The change these flags make to a scene's grid.
    pub fn grid_override(&self) -> GridOverride {
        GridOverride {
            resolution: self.resolution,
            max_resolution: self.preview.then_some(PREVIEW_RESOLUTION),
            smoothing: self.smoothing,
        }
    }

    /// Whether any flag changes the scene.
    pub fn any(&self) -> bool {
        self.resolution.is_some() || self.smoothing.is_some() || self.preview
    }

    /// Read `path` with these flags applied; when they change the grid, say
    /// on stderr what will be built and the memory it needs.
    pub fn load(&self, path: &Path) -> Result<Scene> {
        let scene = Scene::load_with(path, &self.grid_override())?;
        if self.any() {
            eprintln!("{}", describe(&scene));
        }
        Ok(scene)
    }

    /// [`GridFlags::load`] for scene text (`origin` names it).
    pub fn parse(&self, text: &str, origin: &str) -> Result<Scene> {
        let scene = Scene::parse_with(text, origin, &self.grid_override())?;
        if self.any() {
            eprintln!("{}", describe(&scene));
        }
        Ok(scene)
    }
}

/// Bytes the light volumes of `scene` take: per light an RGB fluence and
/// one net-flux vector per channel traced (three with dispersion), f32,
/// and while simulating the fixed-point counters (`deposit::Counters`:
/// three u64 fluence and three i64 flux words per cell and channel group).
pub fn light_volume_bytes(scene: &Scene) -> (u128, u128) {
    let cells = scene
        .grid
        .geometry
        .dims
        .iter()
        .map(|&d| d as u128)
        .product::<u128>();
    let flux_arrays = if scene.grid.dispersion { 3 } else { 1 };
    let per_light = cells * 4 * 3 * (1 + flux_arrays);
    let counters = cells * 8 * 3 * (1 + flux_arrays);
    (per_light * scene.lights.len() as u128, counters)
}

/// One line: the grid that will be built and the memory it needs.
pub fn describe(scene: &Scene) -> String {
    let g = &scene.grid;
    let [nx, ny, nz] = g.geometry.dims;
    let mem = Medium::memory_estimate(scene);
    let (light, counters) = light_volume_bytes(scene);
    format!(
        "grid {nx} x {ny} x {nz} voxels, smoothing {} voxel: medium {} ({} peak while building), light volumes {} (+{} while simulating one light)",
        g.smoothing,
        format_bytes(mem.resident),
        format_bytes(mem.peak),
        format_bytes(light),
        format_bytes(counters),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn smoothing_flag_is_checked() {
        assert_eq!(parse_smoothing("0.5"), Ok(0.5));
        assert!(parse_smoothing("9").is_err());
        assert!(parse_smoothing("-1").is_err());
        assert!(parse_smoothing("nan").is_err());
        assert!(parse_smoothing("x").is_err());
    }

    #[test]
    fn preview_caps_and_resolution_sets() {
        let p = GridFlags {
            preview: true,
            ..GridFlags::default()
        };
        assert_eq!(p.grid_override().max_resolution, Some(PREVIEW_RESOLUTION));
        assert!(p.any());
        assert!(!GridFlags::default().any());
    }
}
