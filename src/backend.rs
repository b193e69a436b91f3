//! `--backend cpu|gpu`: where the light simulation and the renderer run.
//!
//! Without the flag a hardware GPU is used when one exists, else the CPU,
//! and the choice is said on stderr. A software adapter (Mesa's lavapipe,
//! wgpu's `DeviceType::Cpu`) is never chosen by default: it emulates the
//! GPU on the same cores the CPU backend uses, more slowly; `--backend gpu`
//! forces it (the CI parity tests do).
//!
//! An eikon built without the `gpu` feature (`--no-default-features`) has
//! the CPU only: `--backend gpu` is then an error that says so, and the
//! default is the CPU.

use anyhow::Result;
use clap::ValueEnum;
#[cfg(feature = "gpu")]
use eikon_gpu::{Gpu, GpuError};
use eikon_grid::{Light, Medium, Progress, Scene};
use eikon_optics::{Camera, Environment};
use eikon_wavefront::{LightVolume, Summary};
use std::sync::Mutex;

/// The `--backend` values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum BackendArg {
    /// rayon on the CPU cores.
    Cpu,
    /// wgpu compute shaders (Vulkan, Metal or DX12).
    Gpu,
}

/// The `--backend` flag, shared by every command that simulates or renders.
#[derive(clap::Args, Clone, Copy, Debug, Default)]
pub struct BackendFlag {
    /// Where to simulate and render (default: a hardware GPU when one
    /// exists, else the CPU; a software adapter such as lavapipe only when
    /// asked for with `gpu`).
    #[arg(long, value_enum)]
    pub backend: Option<BackendArg>,
}

/// The backend chosen.
pub enum Backend {
    /// The CPU (rayon).
    Cpu,
    /// A GPU device.
    #[cfg(feature = "gpu")]
    Gpu(Box<Gpu>),
}

impl Backend {
    /// Short name for tables and JSON.
    pub fn name(&self) -> &'static str {
        match self {
            Backend::Cpu => "cpu",
            #[cfg(feature = "gpu")]
            Backend::Gpu(_) => "gpu",
        }
    }

    /// A description: `cpu (N threads)` or the adapter.
    pub fn describe(&self) -> String {
        match self {
            Backend::Cpu => format!("cpu ({} threads)", rayon::current_num_threads()),
            #[cfg(feature = "gpu")]
            Backend::Gpu(g) => format!("gpu: {}", g.describe()),
        }
    }
}

impl Backend {
    /// The light simulator of this backend for `medium`: on the GPU the
    /// medium is uploaded here, once for every light.
    /// With `[grid] interfaces = "sharp"` the simulation crosses the
    /// scene's exact surfaces (on the GPU, for the shapes its region table
    /// holds: `eikon_grid::region::gpu_regions`).
    /// `regions`, where given, are the scene's regions already cleared
    /// ([`eikon_grid::Regions::clear_of`]) of a medium whose boundary
    /// indicator is since released.
    pub fn simulator<'a>(
        &'a self,
        medium: &'a Medium,
        scene: &'a Scene,
        regions: Option<eikon_grid::Regions<'a>>,
    ) -> Result<Simulator<'a>> {
        let sharp = scene.grid.interfaces == eikon_grid::Interfaces::Sharp;
        let regions =
            || regions.unwrap_or_else(|| eikon_grid::Regions::new(scene).clear_of(medium));
        Ok(match self {
            Backend::Cpu => Simulator::Cpu(medium, sharp.then(|| Box::new(regions()))),
            #[cfg(feature = "gpu")]
            Backend::Gpu(g) => {
                use eikon_wavefront::gpu::GpuSimulator;
                // Sharp interfaces on the GPU: spheres, boxes, cylinders and
                // half-spaces; any other object is an error naming it (and
                // the way out: --backend cpu or --interfaces smoothed).
                let sim = if sharp {
                    GpuSimulator::with_regions(g, medium, regions())?
                } else {
                    GpuSimulator::new(g, medium)?
                };
                Simulator::Gpu(Box::new(sim))
            }
        })
    }

    /// Host memory the GPU light simulator's buffers take, for the memory
    /// check (`None` on the CPU or a discrete GPU: see [`host_bytes`]),
    /// with `sharp` interfaces or without.
    pub fn simulator_host_bytes(
        &self,
        dims: [usize; 3],
        channels: usize,
        opts: &eikon_wavefront::Options,
        sharp: bool,
    ) -> Option<u64> {
        match self {
            Backend::Cpu => {
                let _ = (dims, channels, opts, sharp);
                None
            }
            #[cfg(feature = "gpu")]
            Backend::Gpu(g) => host_bytes(
                g,
                eikon_wavefront::gpu::GpuSimulator::device_bytes(dims, channels, opts, sharp),
            ),
        }
    }

    /// Host memory the GPU renderer's buffers and textures take, for the
    /// memory check (`None` on the CPU or a discrete GPU: see
    /// [`host_bytes`]).
    pub fn renderer_host_bytes(
        &self,
        medium: &Medium,
        volumes: &[LightVolume],
        env: &Environment,
        camera: &Camera,
        opts: &eikon_view::Options,
    ) -> Option<u64> {
        match self {
            Backend::Cpu => {
                let _ = (medium, volumes, env, camera, opts);
                None
            }
            #[cfg(feature = "gpu")]
            Backend::Gpu(g) => {
                let size = eikon_view::gpu::DeviceSize::of(medium, volumes, env, camera, opts);
                host_bytes(g, eikon_view::gpu::GpuRenderer::device_bytes(&size))
            }
        }
    }
}

/// Where each light of a run is simulated.
pub enum Simulator<'a> {
    /// [`eikon_wavefront::simulate_light_in`] on the CPU cores, with the
    /// scene's regions for sharp interfaces.
    Cpu(&'a Medium, Option<Box<eikon_grid::Regions<'a>>>),
    /// The wgpu compute simulation, the medium uploaded.
    #[cfg(feature = "gpu")]
    Gpu(Box<eikon_wavefront::gpu::GpuSimulator<'a>>),
}

impl Simulator<'_> {
    /// Simulate `light`.
    pub fn simulate(
        &self,
        light: &Light,
        opts: &eikon_wavefront::Options,
        progress: Progress,
    ) -> Result<(LightVolume, Summary), eikon_wavefront::Error> {
        match self {
            Simulator::Cpu(medium, regions) => eikon_wavefront::simulate_light_in(
                light,
                medium,
                regions.as_deref(),
                opts,
                progress,
            ),
            #[cfg(feature = "gpu")]
            Simulator::Gpu(sim) => sim.simulate(light, opts, progress),
        }
    }
}

/// `bytes` of GPU buffers and textures as host memory: on a software
/// adapter (lavapipe) or an integrated GPU they are host memory and count
/// against the limit; a discrete GPU's own memory does not (its driver
/// refuses what does not fit, and `Gpu::checked` reports that).
#[cfg(feature = "gpu")]
fn host_bytes(gpu: &Gpu, bytes: u64) -> Option<u64> {
    matches!(
        gpu.info.device_type,
        wgpu::DeviceType::Cpu | wgpu::DeviceType::IntegratedGpu
    )
    .then_some(bytes)
}

/// Every backend this machine can run, the GPU adapter (or why there is
/// none) said on stderr: what `eikon bench` runs without `--backends`.
pub fn available() -> Vec<BackendArg> {
    #[cfg(feature = "gpu")]
    match Gpu::new() {
        Ok(g) => {
            eprintln!(
                "GPU adapter: {}{}",
                g.describe(),
                if is_software(&g) {
                    " (software: the CPU-emulated baseline)"
                } else {
                    ""
                }
            );
            vec![BackendArg::Cpu, BackendArg::Gpu]
        }
        Err(e) => {
            eprintln!("no GPU backend: {e}");
            vec![BackendArg::Cpu]
        }
    }
    #[cfg(not(feature = "gpu"))]
    {
        eprintln!("no GPU backend: built without the `gpu` feature");
        vec![BackendArg::Cpu]
    }
}

/// Whether an adapter is a software emulation of a GPU.
#[cfg(feature = "gpu")]
pub fn is_software(gpu: &Gpu) -> bool {
    gpu.info.device_type == wgpu::DeviceType::Cpu
}

/// Why the CPU, when no GPU adapter exists: what would change that, and
/// why a software Vulkan would not help.
#[cfg(feature = "gpu")]
const NO_ADAPTER: &str = " (no GPU adapter: a hardware GPU's Vulkan, Metal or DX12 driver would enable the GPU backend; a software Vulkan such as lavapipe is for testing only, slower than the CPU)";

/// Why `--backend gpu` fails in an eikon built without the `gpu` feature.
#[cfg(not(feature = "gpu"))]
pub const NO_GPU_FEATURE: &str = "--backend gpu: this eikon was built without the `gpu` feature; rebuild with default features (`cargo build --release`) to use the GPU";

/// What [`BackendFlag::select`] chose and why, said by [`announce`] once
/// the work starts (so that bad input is reported first, alone).
static NOTE: Mutex<Option<String>> = Mutex::new(None);

/// Say on stderr which backend was chosen, once, if there is anything left
/// to say.
pub fn announce() {
    if let Some(note) = NOTE.lock().ok().and_then(|mut n| n.take()) {
        eprintln!("{note}");
    }
}

impl BackendFlag {
    /// Choose; [`announce`] says which on stderr (`quiet`: never).
    pub fn select(&self, quiet: bool) -> Result<Backend> {
        let say = |b: &Backend, why: &str| {
            if !quiet {
                if let Ok(mut n) = NOTE.lock() {
                    *n = Some(format!("backend: {}{why}", b.describe()));
                }
            }
        };
        match self.backend {
            Some(BackendArg::Cpu) => {
                let b = Backend::Cpu;
                say(&b, "");
                Ok(b)
            }
            #[cfg(not(feature = "gpu"))]
            Some(BackendArg::Gpu) => anyhow::bail!(NO_GPU_FEATURE),
            #[cfg(not(feature = "gpu"))]
            None => {
                let b = Backend::Cpu;
                say(&b, "");
                Ok(b)
            }
            #[cfg(feature = "gpu")]
            Some(BackendArg::Gpu) => {
                let b = Backend::Gpu(Box::new(Gpu::new()?));
                say(&b, "");
                Ok(b)
            }
            #[cfg(feature = "gpu")]
            None => match Gpu::new() {
                Ok(g) if !is_software(&g) => {
                    let b = Backend::Gpu(Box::new(g));
                    say(&b, " (--backend cpu to use the CPU)");
                    Ok(b)
                }
                Ok(g) => {
                    let b = Backend::Cpu;
                    say(
                        &b,
                        &format!(
                            " (the only GPU adapter, {}, is a software emulation, slower than the CPU backend on this machine; --backend gpu forces it)",
                            g.describe()
                        ),
                    );
                    Ok(b)
                }
                Err(GpuError::NoAdapter { .. }) => {
                    let b = Backend::Cpu;
                    say(&b, NO_ADAPTER);
                    Ok(b)
                }
                Err(e) => {
                    let b = Backend::Cpu;
                    say(&b, &format!(" ({e})"));
                    Ok(b)
                }
            },
        }
    }
}

#[cfg(all(test, not(feature = "gpu")))]
mod tests {
    use super::*;

    #[test]
    fn without_the_gpu_feature_gpu_is_an_error_and_the_default_is_the_cpu() {
        let gpu = BackendFlag {
            backend: Some(BackendArg::Gpu),
        };
        let e = gpu.select(true).err().expect("--backend gpu must fail");
        assert!(e.to_string().contains("without the `gpu` feature"), "{e}");
        let auto = BackendFlag::default().select(true).unwrap();
        assert_eq!(auto.name(), "cpu");
    }
}
