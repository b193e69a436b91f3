//! `eikon render --method wyman` and the `wyman` row of `eikon compare`:
//! Wyman's image-space refraction and caustic maps (`eikon-wyman`) on the
//! GPU's render pipelines, shaded on the CPU through the scene's
//! surroundings. An eikon built without the `gpu` feature refuses the
//! method ([`device`]) and has no `eikon-wyman`.

use crate::backend::BackendArg;
use crate::render::Overrides;
use anyhow::{bail, Result};
use clap::ValueEnum;
use eikon_grid::Scene;
use eikon_optics::Image;
#[cfg(feature = "gpu")]
use eikon_wyman::{Settings, Stats, Tir};
#[cfg(feature = "gpu")]
use serde_json::json;
#[cfg(feature = "gpu")]
use std::time::Instant;

/// The device the method runs on.
#[cfg(feature = "gpu")]
pub type Device = eikon_gpu::Gpu;

/// Without the `gpu` feature there is none ([`device`] fails).
#[cfg(not(feature = "gpu"))]
pub enum Device {}

/// What a frame did (see `eikon_wyman::Stats`).
#[cfg(not(feature = "gpu"))]
pub enum Stats {}

/// What total internal reflection at the back surface becomes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum TirArg {
    /// One refraction only: the ray goes on as refracted at the front.
    Single,
    /// Leave along the surface (the incidence clamped to the critical angle).
    Clamp,
    /// Reflect at the back and ignore the object after.
    Reflect,
}

/// Settings of `--method wyman`.
#[derive(clap::Args, Clone, Default)]
pub struct WymanOptions {
    /// Photons per side of each light's view (wyman; default 512).
    #[arg(long)]
    pub photons: Option<u32>,
    /// Texels per side of each light's caustic map, over twice the photons'
    /// view (wyman; default 512).
    #[arg(long)]
    pub caustic_map: Option<u32>,
    /// Total internal reflection at the back surface (wyman; default
    /// reflect).
    #[arg(long, value_enum)]
    pub tir: Option<TirArg>,
}

impl WymanOptions {
    /// The settings as a frame manifest records them.
    pub fn describe(&self) -> String {
        #[cfg(feature = "gpu")]
        return format!("{:?}", self.settings());
        #[cfg(not(feature = "gpu"))]
        return format!("{:?}", (self.photons, self.caustic_map, self.tir));
    }

    /// The frame settings.
    #[cfg(feature = "gpu")]
    pub fn settings(&self) -> Settings {
        let d = Settings::default();
        Settings {
            photons: self.photons.unwrap_or(d.photons),
            caustic_map: self.caustic_map.unwrap_or(d.caustic_map),
            tir: match self.tir {
                Some(TirArg::Single) => Tir::Single,
                Some(TirArg::Clamp) => Tir::Clamp,
                Some(TirArg::Reflect) | None => Tir::Reflect,
            },
            ..d
        }
    }
}

/// The device for `--method wyman`: any Vulkan, Metal or DX12 adapter, a
/// software one included (the method has no CPU path).
#[cfg(feature = "gpu")]
pub fn device() -> Result<Device> {
    use anyhow::Context;
    let gpu = match Device::new() {
        Err(eikon_gpu::GpuError::NoAdapter { wanted }) => bail!(
            "--method wyman: no GPU adapter found ({wanted}): the method runs on a Vulkan, Metal or DX12 device's render pipelines (a software Vulkan such as Mesa's lavapipe will do); --method eikonal or an exact method render without one"
        ),
        other => other.context("--method wyman")?,
    };
    eprintln!("wyman: {}", gpu.describe());
    Ok(gpu)
}

/// Without the `gpu` feature: the method is not built in.
#[cfg(not(feature = "gpu"))]
pub fn device() -> Result<Device> {
    bail!("--method wyman: this eikon was built without the `gpu` feature; rebuild with default features (`cargo build --release`) to use the image-space method")
}

/// Refuse `--backend cpu` for `render --method wyman`.
pub fn check_backend(overrides: &Overrides) -> Result<()> {
    if overrides.backend.backend == Some(BackendArg::Cpu) {
        bail!("--backend cpu: --method wyman runs on the GPU's render pipelines only (a software Vulkan such as lavapipe will do)");
    }
    Ok(())
}

/// Render `scene` by the image-space method: the image, what it did and
/// the seconds it took.
#[cfg(feature = "gpu")]
pub fn image(
    gpu: &Device,
    scene: &Scene,
    overrides: &Overrides,
    options: &WymanOptions,
) -> Result<(Image, Stats, f64)> {
    let camera = crate::render::camera(scene, overrides)?;
    let settings = options.settings();
    let started = Instant::now();
    let (image, stats) = eikon_wyman::render(gpu, scene, &camera, &settings)?;
    Ok((image, stats, started.elapsed().as_secs_f64()))
}

/// Without the `gpu` feature there is no device to render on.
#[cfg(not(feature = "gpu"))]
pub fn image(
    gpu: &Device,
    _: &Scene,
    _: &Overrides,
    _: &WymanOptions,
) -> Result<(Image, Stats, f64)> {
    match *gpu {}
}

/// Refuse a scene the image-space method cannot render (before any
/// work), and say what it leaves out of the one it can.
#[cfg(feature = "gpu")]
pub fn check(scene: &Scene) -> Result<()> {
    let r = eikon_wyman::render::check(scene)?;
    for u in &r.unhandled {
        eprintln!("warning: {}: {u}", scene.origin);
    }
    Ok(())
}

/// Without the `gpu` feature: the method is not built in.
#[cfg(not(feature = "gpu"))]
pub fn check(_: &Scene) -> Result<()> {
    device().map(|d| match d {})
}

/// `eikon render --method wyman` of one frame: write `outputs` and report.
#[cfg(feature = "gpu")]
pub fn render(
    scene: &Scene,
    overrides: &Overrides,
    options: &WymanOptions,
    outputs: &[std::path::PathBuf],
    json_out: bool,
) -> Result<()> {
    check_backend(overrides)?;
    check(scene)?;
    let gpu = device()?;
    let (image, stats, seconds) = image(&gpu, scene, overrides, options)?;
    crate::render::write_images(outputs, &image, &crate::render::tone(scene, overrides))?;
    let names: Vec<String> = outputs.iter().map(|p| p.display().to_string()).collect();
    if json_out {
        println!(
            "{}",
            serde_json::to_string_pretty(&json!({
                "method": "wyman",
                "outputs": names,
                "width": image.width,
                "height": image.height,
                "seconds": seconds,
                "passes": stats.passes,
                "covered": stats.covered,
                "tir_back": stats.tir_back,
                "fallback_normal": stats.fallback_normal,
                "caustic_lights": stats.caustic_lights,
                "readback_bytes": stats.readback_bytes,
                "caustic_seconds": stats.caustic_seconds,
                "eye_seconds": stats.eye_seconds,
                "shade_seconds": stats.shade_seconds,
            }))?
        );
    } else {
        println!(
            "rendered {} x {} with wyman in {seconds:.3} s ({} render passes, {} refracted pixel samples, {} with total internal reflection at the back, {} lights with caustic maps); wrote {}",
            image.width,
            image.height,
            stats.passes,
            stats.covered,
            stats.tir_back,
            stats.caustic_lights,
            names.join(", ")
        );
    }
    Ok(())
}

/// Without the `gpu` feature: the method is not built in.
#[cfg(not(feature = "gpu"))]
pub fn render(
    _: &Scene,
    _: &Overrides,
    _: &WymanOptions,
    _: &[std::path::PathBuf],
    _: bool,
) -> Result<()> {
    device().map(|d| match d {})
}
