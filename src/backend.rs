//! `--backend cpu|gpu`: where the light simulation and the renderer run.
//!
//! Without the flag a hardware GPU is used when one exists, else the CPU,
//! and the choice is said on stderr. A software adapter (Mesa's lavapipe,
//! wgpu's `DeviceType::Cpu`) is never chosen by default: it emulates the
//! GPU on the same cores the CPU backend uses, more slowly; `--backend gpu`
//! forces it (the CI parity tests do).

use anyhow::Result;
use clap::ValueEnum;
use eikon_gpu::{Gpu, GpuError};
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
    Gpu(Box<Gpu>),
}

impl Backend {
    /// Short name for tables and JSON.
    pub fn name(&self) -> &'static str {
        match self {
            Backend::Cpu => "cpu",
            Backend::Gpu(_) => "gpu",
        }
    }

    /// A description: `cpu (N threads)` or the adapter.
    pub fn describe(&self) -> String {
        match self {
            Backend::Cpu => format!("cpu ({} threads)", rayon::current_num_threads()),
            Backend::Gpu(g) => format!("gpu: {}", g.describe()),
        }
    }
}

/// Whether an adapter is a software emulation of a GPU.
pub fn is_software(gpu: &Gpu) -> bool {
    gpu.info.device_type == wgpu::DeviceType::Cpu
}

/// Why the CPU, when no GPU adapter exists: what would change that, and
/// why a software Vulkan would not help.
const NO_ADAPTER: &str = " (no GPU adapter: a hardware GPU's Vulkan, Metal or DX12 driver would enable the GPU backend; a software Vulkan such as lavapipe is for testing only, slower than the CPU)";

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
            Some(BackendArg::Gpu) => {
                let b = Backend::Gpu(Box::new(Gpu::new()?));
                say(&b, "");
                Ok(b)
            }
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
