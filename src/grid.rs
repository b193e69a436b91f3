//! `--resolution`, `--smoothing` and `--preview`: the command line's say
//! over a scene's `[grid]`, shared by every command that builds a medium.

use anyhow::{bail, Result};
use eikon_grid::field::{available_memory, format_bytes};
use eikon_grid::{GridOverride, Interfaces, Medium, Scene};
use std::path::Path;
use std::sync::OnceLock;

/// `--max-memory`, once given: the limit every memory check of this
/// process uses instead of the memory the system reports available.
static MAX_MEMORY: OnceLock<u128> = OnceLock::new();

/// The memory a command may use: `--max-memory` if given, else what the
/// system reports available (unbounded where it reports nothing).
pub fn memory_limit() -> u128 {
    MAX_MEMORY
        .get()
        .copied()
        .unwrap_or_else(|| available_memory().unwrap_or(u128::MAX))
}

/// Bytes from `8G`, `512M`, `64K` or a plain number (binary units).
fn parse_bytes(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let (num, unit) = match t.char_indices().find(|(_, c)| c.is_ascii_alphabetic()) {
        Some((i, _)) => (&t[..i], t[i..].to_ascii_uppercase()),
        None => (t, String::new()),
    };
    let shift = match unit.trim_end_matches("IB").trim_end_matches('B') {
        "" => 0,
        "K" => 10,
        "M" => 20,
        "G" => 30,
        "T" => 40,
        _ => return Err(format!("unknown unit in {s:?}: use K, M, G or T")),
    };
    let v: f64 = num.trim().parse().map_err(|e| format!("{s:?}: {e}"))?;
    let bytes = v * (1u64 << shift) as f64;
    if !(bytes.is_finite() && bytes >= 1.0 && bytes < 2f64.powi(63)) {
        return Err(format!("{s:?} is not a usable amount of memory"));
    }
    Ok(bytes as u64)
}

/// The most voxels along the longest axis `--resolution` accepts (the
/// memory check refuses what will not fit long before this).
pub const MAX_RESOLUTION: u64 = 4096;

/// Voxels along the longest axis with `--preview` (unless the scene has
/// fewer, or `--resolution` says otherwise).
pub const PREVIEW_RESOLUTION: u64 = 48;

/// The image width `--preview` renders at most, in pixels.
pub const PREVIEW_WIDTH: u32 = 320;

/// `--interfaces`: `sharp` or `smoothed`.
pub fn parse_interfaces(s: &str) -> Result<Interfaces, String> {
    match s {
        "sharp" => Ok(Interfaces::Sharp),
        "smoothed" => Ok(Interfaces::Smoothed),
        _ => Err(format!("expected `sharp` or `smoothed`, got `{s}`")),
    }
}

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
    /// How rays meet the surfaces between materials, instead of the scene's
    /// `[grid] interfaces`: `sharp` (exact surfaces, the index of each
    /// region inside it) or `smoothed` (the paper's smoothed index).
    #[arg(long, value_parser = parse_interfaces)]
    pub interfaces: Option<Interfaces>,
    /// A fast first look: at most 48 voxels along the longest axis and, for
    /// images, at most 320 pixels wide with one sample per pixel.
    #[arg(long)]
    pub preview: bool,
    /// Memory the run may use (e.g. 8G, 512M), instead of what the system
    /// reports available: every estimate is checked against it.
    #[arg(long, value_parser = parse_bytes)]
    pub max_memory: Option<u64>,
}

impl GridFlags {
    /// The change these flags make to a scene's grid.
    pub fn grid_override(&self) -> GridOverride {
        GridOverride {
            resolution: self.resolution,
            max_resolution: self.preview.then_some(PREVIEW_RESOLUTION),
            smoothing: self.smoothing,
            interfaces: self.interfaces,
        }
    }

    fn set_limit(&self) {
        if let Some(m) = self.max_memory {
            let _ = MAX_MEMORY.set(m as u128);
        }
    }

    /// Whether any flag changes the scene.
    pub fn any(&self) -> bool {
        self.resolution.is_some()
            || self.smoothing.is_some()
            || self.interfaces.is_some()
            || self.preview
    }

    /// Read `path` with these flags applied; when they change the grid, say
    /// on stderr what will be built and the memory it needs.
    pub fn load(&self, path: &Path) -> Result<Scene> {
        self.set_limit();
        let scene = Scene::load_with(path, &self.grid_override())?;
        if self.any() {
            eprintln!("{}", describe(&scene));
        }
        Ok(scene)
    }

    /// Read `path` as an animation (a static scene is one frame) with these
    /// flags applied to every frame.
    pub fn load_animation(&self, path: &Path) -> Result<eikon_grid::animation::Animation> {
        self.set_limit();
        Ok(eikon_grid::animation::Animation::load_with(
            path,
            &self.grid_override(),
        )?)
    }

    /// [`GridFlags::load`] for scene text (`origin` names it).
    pub fn parse(&self, text: &str, origin: &str) -> Result<Scene> {
        self.set_limit();
        let scene = Scene::parse_with(text, origin, &self.grid_override())?;
        if self.any() {
            eprintln!("{}", describe(&scene));
        }
        Ok(scene)
    }
}

/// Cells of `scene`'s grid.
fn cells(scene: &Scene) -> u128 {
    scene
        .grid
        .geometry
        .dims
        .iter()
        .map(|&d| d as u128)
        .product()
}

/// Bytes the light volumes of `scene` take: per light an RGB fluence and
/// one net-flux vector per channel traced (three with dispersion), f32,
/// and while simulating the fixed-point counters (`deposit::Counters`:
/// three u64 fluence and three i64 flux words per cell and channel group).
pub fn light_volume_bytes(scene: &Scene) -> (u128, u128) {
    let cells = cells(scene);
    let flux_arrays = if scene.grid.dispersion { 3 } else { 1 };
    let per_light = cells * 4 * 3 * (1 + flux_arrays);
    let counters = cells * 8 * 3 * (1 + flux_arrays);
    (per_light * scene.lights.len() as u128, counters)
}

/// What a command holds at its peak besides the medium.
#[derive(Clone, Copy, Debug, Default)]
pub struct Needs {
    /// The medium's render properties are released
    /// (`Medium::release_render_properties`, `eikon simulate`).
    pub light_only: bool,
    /// The medium holds its surfaces alone
    /// (`Medium::build_surfaces_within`: `eikon simulate` with sharp
    /// interfaces on the CPU), and not even those once the regions have
    /// read them (`Medium::release_boundary`).
    pub surfaces_only: bool,
    /// The light volumes of every light (simulate, render).
    pub light_volumes: bool,
    /// The fixed-point counters of one light being simulated.
    pub counters: bool,
    /// A wavefront of at most this many patches.
    pub patches: Option<usize>,
    /// The interface sides Fresnel reads (a simulation with Fresnel).
    pub interfaces: bool,
    /// The photon tracer's working tables.
    pub photons: bool,
    /// The eikonal renderer's packed properties (interface sides included).
    pub renderer: bool,
    /// An image of this many pixels (HDR accumulation and output).
    pub pixels: Option<u64>,
    /// Bytes of GPU buffers and textures (device memory; host memory on a
    /// software adapter such as lavapipe, so counted against the limit).
    pub gpu: Option<u64>,
}

/// The bytes `needs` take for `scene`, item by item.
fn itemize(scene: &Scene, needs: &Needs) -> Vec<(&'static str, u128)> {
    let (light, counters) = light_volume_bytes(scene);
    let est = Medium::memory_estimate(scene);
    let medium = if needs.surfaces_only {
        // Its boundary indicator is released once the regions have read it
        // (`Medium::release_boundary`), before the counters are allocated;
        // the build's own peak is `check_memory`'s floor.
        0
    } else if needs.light_only {
        est.light
    } else {
        est.resident
    };
    let mut items = vec![("medium", medium)];
    if needs.light_volumes {
        items.push(("light volumes", light));
    }
    if needs.counters {
        items.push(("deposit counters", counters));
    }
    if let Some(n) = needs.patches {
        let bytes = n as u128 * eikon_wavefront::Patches::BYTES_PER_PATCH as u128;
        items.push(("patch list at its cap", bytes));
    }
    let cells = cells(scene);
    let channels = scene.channels();
    if needs.interfaces {
        items.push((
            "interface sides",
            eikon_grid::interface::Interfaces::bytes(cells, channels),
        ));
    }
    if needs.photons {
        items.push((
            "photon tracer tables",
            eikon_wavefront::photons::working_bytes(cells),
        ));
    }
    if needs.renderer {
        let emits = scene
            .objects
            .iter()
            .any(|o| o.material.emission != glam::DVec3::ZERO);
        items.push((
            "renderer tables",
            eikon_view::properties::Properties::bytes(cells, channels, emits),
        ));
    }
    if let Some(b) = needs.gpu {
        items.push(("GPU buffers", b as u128));
    }
    if let Some(p) = needs.pixels {
        // Linear RGB f32 image, its tone-mapped copy and encoder buffers.
        items.push(("image", p as u128 * 3 * (4 + 4 + 1)));
    }
    items
}

/// Check that a command with `needs` fits the memory limit: the bytes it
/// will hold at its peak (the medium's build peak or everything it holds
/// while running, whichever is larger), else an error listing what takes
/// them.
pub fn check_memory(scene: &Scene, needs: &Needs) -> Result<u128> {
    let items = itemize(scene, needs);
    let total: u128 = items.iter().map(|(_, b)| b).sum();
    let limit = memory_limit();
    if total > limit {
        let list: Vec<String> = items
            .iter()
            .map(|(what, b)| format!("{what} {}", format_bytes(*b)))
            .collect();
        bail!(
            "{}: the run needs {} ({}) but {} is the limit (--max-memory, else what is available): lower --resolution, --max-patches or the image size",
            scene.origin,
            format_bytes(total),
            list.join(", "),
            format_bytes(limit)
        );
    }
    let est = Medium::memory_estimate(scene);
    Ok(total.max(if needs.surfaces_only {
        est.surfaces_peak
    } else {
        est.peak
    }))
}

/// The most memory this process has held resident (Linux `VmHWM`), to
/// report beside the estimate; `None` where the system does not say.
pub fn peak_resident() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line
        .trim_start_matches("VmHWM:")
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(kib * 1024)
}

/// The most patches that fit the memory limit once everything else a
/// simulation holds (`rest`: its medium as it is held, volumes, counters)
/// is counted, at most `cap`.
pub fn patches_that_fit(scene: &Scene, cap: usize, rest: &Needs) -> usize {
    patches_within(scene, cap, rest, memory_limit())
}

/// [`patches_that_fit`] under `limit` bytes.
fn patches_within(scene: &Scene, cap: usize, rest: &Needs, limit: u128) -> usize {
    let rest = Needs {
        patches: None,
        ..*rest
    };
    let held: u128 = itemize(scene, &rest).iter().map(|(_, b)| b).sum();
    let fit = limit.saturating_sub(held) / eikon_wavefront::Patches::BYTES_PER_PATCH as u128;
    (fit.min(cap as u128)) as usize
}

/// One line: the grid that will be built and the memory it needs.
pub fn describe(scene: &Scene) -> String {
    let g = &scene.grid;
    let [nx, ny, nz] = g.geometry.dims;
    let mem = Medium::memory_estimate(scene);
    let (light, counters) = light_volume_bytes(scene);
    // What `eikon simulate` builds for the wavefront on the CPU.
    let surfaces = if g.interfaces == eikon_grid::Interfaces::Sharp {
        format!(
            "; to simulate on the CPU, the surfaces alone: {}, {} peak",
            format_bytes(mem.surfaces),
            format_bytes(mem.surfaces_peak)
        )
    } else {
        String::new()
    };
    format!(
        "grid {nx} x {ny} x {nz} voxels, smoothing {} voxel: medium {} ({} peak while building{surfaces}), light volumes {} (+{} while simulating one light)",
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
    fn a_medium_for_the_light_alone_counts_without_its_render_properties_or_its_voxel_fields() {
        let scene = Scene::parse(
            "[grid]\nresolution = 12\nmin = [-1, -1, -1]\nmax = [1, 1, 1]\n\n[[object]]\nshape = { type = \"sphere\", center = [0, 0, 0], radius = 0.5 }\nindex = 1.5\nalbedo = [0.5, 0.5, 0.5]\n",
            "test",
        )
        .unwrap();
        let bytes = |a: usize| (a * 4) as u128;
        let mut m = Medium::build(&scene).unwrap();
        let est = Medium::memory_estimate(&scene);
        let held = |m: &Medium| {
            m.index.iter().map(|a| bytes(a.len())).sum::<u128>()
                + [&m.extinction, &m.albedo, &m.emission]
                    .iter()
                    .map(|a| bytes(a.len()))
                    .sum::<u128>()
                + bytes(m.g.len())
                + bytes(m.boundary.len())
        };
        assert_eq!(held(&m), est.resident);
        m.release_render_properties();
        assert_eq!(held(&m), est.light);
        let mut lean = Medium::build_surfaces_within(&scene, u128::MAX, &|_, _, _| {}).unwrap();
        assert_eq!(held(&lean), est.surfaces);
        lean.release_boundary();
        assert_eq!(held(&lean), 0);
        let medium = |light_only, surfaces_only| {
            itemize(
                &scene,
                &Needs {
                    light_only,
                    surfaces_only,
                    ..Needs::default()
                },
            )[0]
            .1
        };
        assert_eq!(
            (
                medium(false, false),
                medium(true, false),
                medium(true, true)
            ),
            (est.resident, est.light, 0)
        );
    }

    /// The patch cap that fits a limit counts the medium as the run holds
    /// it: a simulation of the surfaces alone (its boundary indicator
    /// released) has the whole resident medium's bytes more for patches.
    #[test]
    fn the_patches_that_fit_count_the_medium_as_held() {
        let scene = Scene::parse(
            "[grid]\nresolution = 24\nmin = [-1, -1, -1]\nmax = [1, 1, 1]\n\n[[object]]\nshape = { type = \"sphere\", center = [0, 0, 0], radius = 0.5 }\nindex = 1.5\n",
            "test",
        )
        .unwrap();
        let est = Medium::memory_estimate(&scene);
        let per = eikon_wavefront::Patches::BYTES_PER_PATCH as u128;
        let run = |surfaces_only| Needs {
            surfaces_only,
            light_volumes: true,
            counters: true,
            ..Needs::default()
        };
        let (light, counters) = light_volume_bytes(&scene);
        let limit = light + counters + est.resident + 1000 * per;
        assert_eq!(patches_within(&scene, usize::MAX, &run(false), limit), 1000);
        let lean = patches_within(&scene, usize::MAX, &run(true), limit);
        assert_eq!(lean as u128, 1000 + est.resident / per);
        // The cap bounds it, and a limit below what the rest holds leaves
        // none.
        assert_eq!(patches_within(&scene, 10, &run(true), limit), 10);
        assert_eq!(patches_within(&scene, 10, &run(false), light), 0);
    }

    #[test]
    fn smoothing_flag_is_checked() {
        assert_eq!(parse_smoothing("0.5"), Ok(0.5));
        assert!(parse_smoothing("9").is_err());
        assert!(parse_smoothing("-1").is_err());
        assert!(parse_smoothing("nan").is_err());
        assert!(parse_smoothing("x").is_err());
    }

    #[test]
    fn memory_amounts_parse() {
        assert_eq!(parse_bytes("512"), Ok(512));
        assert_eq!(parse_bytes("64K"), Ok(64 << 10));
        assert_eq!(parse_bytes("1.5G"), Ok(3 << 29));
        assert_eq!(parse_bytes("2GiB"), Ok(2 << 30));
        assert_eq!(parse_bytes("8mb"), Ok(8 << 20));
        for bad in ["", "0", "-1G", "1Q", "nan", "1e30T", "G"] {
            assert!(parse_bytes(bad).is_err(), "{bad}");
        }
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
