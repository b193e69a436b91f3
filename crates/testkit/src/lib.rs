//! # eikon-testkit
//!
//! What eikon's tests share (a dev-dependency only):
//!
//! * [`Tests`]: a test binary's list of tests on [`libtest_mimic`]'s
//!   harness (`harness = false` in the crate's `[[test]]`), with one body
//!   per law run on every backend ([`Tests::both`]: `NAME::cpu` and
//!   `NAME::gpu`) and GPU-only tests ([`Tests::gpu`]). Without a GPU
//!   adapter the GPU tests are reported as **ignored**, in the normal test
//!   output, never passed silently; where the `CI` environment variable is
//!   set (`.ci/run` installs Mesa's lavapipe) they fail instead.
//! * [`Backend`]: the light simulation and the view renderer on the CPU or
//!   a GPU, one call each.
//! * [`metrics`]: agreement measures (median, PSNR after a tone curve,
//!   relative difference of counts).
//! * [`scenes`]: the scenes and options several test files use.
//! * [`parity`]: what the function-level parity tests of the WGSL modules
//!   share.
//! * [`photon_ref`]: an independent photon tracer (sphere, directional,
//!   beam or point light, track-length fluence), sharing no code with
//!   `eikon_wavefront`, to check its volumes against (issue 16).

pub mod metrics;
pub mod parity;
pub mod photon_ref;
pub mod scenes;

use eikon_gpu::Gpu;
use eikon_grid::{Light, Medium, Regions};
use eikon_optics::{Camera, Image};
use eikon_view::gpu::GpuRenderer;
use eikon_view::{Renderer, Stats, Surroundings};
use eikon_wavefront::gpu::GpuSimulator;
use eikon_wavefront::{LightVolume, Summary};
use libtest_mimic::{Arguments, Failed, Trial};
use std::panic::{catch_unwind, AssertUnwindSafe};

/// Where a test body runs.
pub enum Backend<'a> {
    /// The CPU code (f64).
    Cpu,
    /// The wgpu compute kernels (f32) on this device.
    Gpu(&'a Gpu),
}

impl Backend<'_> {
    /// `"cpu"` or `"gpu"`.
    pub fn name(&self) -> &'static str {
        match self {
            Backend::Cpu => "cpu",
            Backend::Gpu(_) => "gpu",
        }
    }

    /// `cpu` on the CPU, `gpu` on a GPU: the size of a test's grid or
    /// image where the GPU runs on a software device in CI (lavapipe, several
    /// times slower than the CPU backend), or an f32 tolerance of a law the
    /// CPU meets in f64.
    pub fn pick<T>(&self, cpu: T, gpu: T) -> T {
        match self {
            Backend::Cpu => cpu,
            Backend::Gpu(_) => gpu,
        }
    }

    /// Simulate `light` in `medium` with `opts` (`eikon_wavefront::
    /// simulate_light` or [`GpuSimulator`]).
    pub fn simulate(
        &self,
        light: &Light,
        medium: &Medium,
        opts: &eikon_wavefront::Options,
    ) -> Result<(LightVolume, Summary), eikon_wavefront::Error> {
        match self {
            Backend::Cpu => eikon_wavefront::simulate_light(light, medium, opts, &|_, _| {}),
            Backend::Gpu(gpu) => GpuSimulator::new(gpu, medium)?.simulate(light, opts, &|_, _| {}),
        }
    }

    /// [`Backend::simulate`] with sharp interfaces: light steps through
    /// `regions` (`eikon_wavefront::simulate_light_in` or
    /// [`GpuSimulator::with_regions`]).
    pub fn simulate_sharp(
        &self,
        light: &Light,
        medium: &Medium,
        regions: Regions,
        opts: &eikon_wavefront::Options,
    ) -> Result<(LightVolume, Summary), eikon_wavefront::Error> {
        match self {
            Backend::Cpu => {
                eikon_wavefront::simulate_light_in(light, medium, Some(&regions), opts, &|_, _| {})
            }
            Backend::Gpu(gpu) => {
                GpuSimulator::with_regions(gpu, medium, regions)?.simulate(light, opts, &|_, _| {})
            }
        }
    }

    /// Render `medium` lit by `volumes` in `surroundings` through `camera`
    /// with `opts` ([`Renderer`] or [`GpuRenderer`]).
    pub fn render(
        &self,
        medium: &Medium,
        volumes: &[LightVolume],
        surroundings: &Surroundings,
        camera: &Camera,
        opts: eikon_view::Options,
    ) -> (Image, Stats) {
        match self {
            Backend::Cpu => {
                Renderer::new(medium, volumes, surroundings, camera, opts).render(&|_, _| {})
            }
            Backend::Gpu(gpu) => GpuRenderer::new(gpu, medium, volumes, surroundings, camera, opts)
                .and_then(|r| r.render_with_stats())
                .unwrap_or_else(|e| panic!("GPU render: {e}")),
        }
    }
}

/// Whether GPU tests can run here, decided once per test binary.
enum Adapter {
    /// An adapter opened: GPU tests run.
    Present(String),
    /// None, and `CI` is unset: GPU tests are ignored.
    Absent(String),
    /// None, and `CI` is set: GPU tests fail.
    Required(String),
}

fn adapter() -> Adapter {
    match Gpu::new() {
        Ok(g) => {
            if std::env::var("WGPU_BACKEND").is_ok_and(|b| b.eq_ignore_ascii_case("vulkan")) {
                assert_eq!(
                    g.info.backend,
                    eikon_gpu::Backend::Vulkan,
                    "WGPU_BACKEND=vulkan, got {}",
                    g.describe()
                );
            }
            Adapter::Present(g.describe())
        }
        Err(e) if std::env::var_os("CI").is_some() => Adapter::Required(e.to_string()),
        Err(e) => Adapter::Absent(e.to_string()),
    }
}

/// A test binary's tests (see the crate docs).
pub struct Tests {
    trials: Vec<Trial>,
    adapter: Adapter,
}

impl Default for Tests {
    fn default() -> Self {
        Self::new()
    }
}

/// Run `f`, turning a panic into a failure with its message.
fn outcome(f: impl FnOnce()) -> Result<(), Failed> {
    catch_unwind(AssertUnwindSafe(f)).map_err(|e| {
        let msg = e
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| e.downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_else(|| "panicked".into());
        Failed::from(msg)
    })
}

impl Tests {
    /// No tests yet; probes for a GPU adapter.
    pub fn new() -> Self {
        Tests {
            trials: Vec::new(),
            adapter: adapter(),
        }
    }

    /// No tests yet, for a binary whose GPU time goes to compiling large
    /// kernels rather than running them (the parity tests of the sharp
    /// regions' WGSL, the view's sharp kernel): on Mesa's software device
    /// (llvmpipe, CI's) LLVM's optimisation passes are skipped
    /// (`GALLIVM_PERF=nopt`, unless set already), which cuts those
    /// binaries' time by a third to a half (docs/PERFORMANCE.md) and slows
    /// binaries that run kernels for long (the light simulations), which
    /// therefore use [`Self::new`]. The kernels compute the same
    /// operations either way; every other driver ignores the variable.
    /// Call it first in `main`, before any thread starts.
    pub fn compile_bound() -> Self {
        if std::env::var_os("GALLIVM_PERF").is_none() {
            // Before the adapter is opened (Mesa reads it once, at its
            // start) and before the harness starts its threads.
            std::env::set_var("GALLIVM_PERF", "nopt");
        }
        Self::new()
    }

    /// A test that needs no GPU.
    pub fn cpu(mut self, name: &str, f: impl FnOnce() + Send + 'static) -> Self {
        self.trials
            .push(Trial::test(name, move || outcome(f)).with_kind("cpu"));
        self
    }

    /// A test of the GPU backend: ignored without an adapter (failed under
    /// `CI`).
    pub fn gpu(mut self, name: &str, f: impl FnOnce(&Gpu) + Send + 'static) -> Self {
        let trial = match &self.adapter {
            Adapter::Present(_) => Trial::test(name, move || {
                let gpu = Gpu::new().map_err(|e| Failed::from(e.to_string()))?;
                outcome(|| f(&gpu))
            }),
            Adapter::Absent(_) => Trial::test(name, || Ok(())).with_ignored_flag(true),
            Adapter::Required(e) => {
                let e = e.clone();
                Trial::test(name, move || {
                    Err(format!("CI must have a GPU adapter (lavapipe): {e}").into())
                })
            }
        };
        self.trials.push(trial.with_kind("gpu"));
        self
    }

    /// A GPU test too slow for every run (a 256^3 grid on a software
    /// device): ignored unless asked for (`-- --ignored`), and then as
    /// [`Self::gpu`].
    pub fn gpu_slow(mut self, name: &str, f: impl FnOnce(&Gpu) + Send + 'static) -> Self {
        self = self.gpu(name, f);
        let last = self.trials.pop().expect("just added");
        self.trials.push(last.with_ignored_flag(true));
        self
    }

    /// One body on every backend: `NAME::cpu` and `NAME::gpu` (the latter
    /// as [`Self::gpu`]).
    pub fn both(self, name: &str, f: impl Fn(&Backend) + Send + Clone + 'static) -> Self {
        let g = f.clone();
        self.cpu(&format!("{name}::cpu"), move || f(&Backend::Cpu))
            .gpu(&format!("{name}::gpu"), move |gpu| g(&Backend::Gpu(gpu)))
    }

    /// Run the tests as `cargo test` runs a binary's tests (filters,
    /// `--ignored`, `--nocapture` work), and exit with their verdict.
    pub fn run(self) -> ! {
        let args = Arguments::from_args();
        match &self.adapter {
            Adapter::Present(name) => eprintln!("GPU tests on {name}"),
            Adapter::Absent(e) => eprintln!("GPU tests ignored: no GPU adapter here ({e})"),
            Adapter::Required(_) => {}
        }
        libtest_mimic::run(&args, self.trials).exit()
    }
}
