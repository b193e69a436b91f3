//! GPU device setup shared by eikon's `gpu` backends (the wavefront light
//! simulator and the view renderer run as wgpu compute shaders).
//!
//! * Only Vulkan, Metal or DX12 adapters are accepted, **never wgpu's
//!   OpenGL fallback**: on Mesa's software GL, 3D storage textures silently
//!   reach only z-slice 0. `WGPU_BACKEND` (e.g. `vulkan`) narrows the
//!   choice further.
//! * Validation errors are caught with error scopes and returned as
//!   [`GpuError::Validation`]; uncaptured errors are recorded, never
//!   panicked on.
//! * No adapter is [`GpuError::NoAdapter`], with a message that says what
//!   was looked for, so a caller can fall back to the CPU.

use std::sync::{Arc, Mutex};
use wgpu::util::DeviceExt;

/// What can go wrong on the GPU.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// No Vulkan, Metal or DX12 adapter.
    #[error("no GPU adapter found ({wanted}): the GPU backend needs a hardware GPU's Vulkan, Metal or DX12 driver; without one, use --backend cpu (a software Vulkan such as lavapipe is for testing only, slower than the CPU backend)")]
    NoAdapter {
        /// The backends that were looked for.
        wanted: String,
    },
    /// The adapter refused a device.
    #[error("the GPU adapter {adapter} refused a device: {message}")]
    Device {
        /// Adapter name.
        adapter: String,
        /// wgpu's reason.
        message: String,
    },
    /// A validation error from wgpu (a bug in our shaders or buffer use).
    #[error("GPU validation error in {what}: {message}")]
    Validation {
        /// The operation.
        what: String,
        /// wgpu's message.
        message: String,
    },
    /// Reading a buffer back failed.
    #[error("reading GPU results back failed: {0}")]
    Readback(String),
    /// Something does not fit the device's limits.
    #[error("{what} needs {need}, but the GPU allows at most {limit} ({hint})")]
    TooLarge {
        /// What was to be allocated.
        what: String,
        /// How much it needs.
        need: u64,
        /// The device's limit.
        limit: u64,
        /// What to do about it.
        hint: String,
    },
}

/// Which graphics API an adapter runs on.
pub type Backend = wgpu::Backend;

/// A GPU device ready for compute.
pub struct Gpu {
    /// The device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// What the adapter is.
    pub info: wgpu::AdapterInfo,
    uncaptured: Arc<Mutex<Vec<String>>>,
}

/// Threads per workgroup of every eikon kernel (1-D).
pub const WORKGROUP: u32 = 64;

impl Gpu {
    /// Open the best Vulkan, Metal or DX12 adapter (never OpenGL), as
    /// narrowed by `WGPU_BACKEND`.
    pub fn new() -> Result<Gpu, GpuError> {
        let allowed = wgpu::Backends::VULKAN | wgpu::Backends::METAL | wgpu::Backends::DX12;
        let backends = wgpu::Backends::from_env().map_or(allowed, |b| b & allowed);
        let instance = wgpu::Instance::new(&wgpu::InstanceDescriptor {
            backends,
            ..Default::default()
        });
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: None,
        }))
        .map_err(|_| GpuError::NoAdapter {
            wanted: format!("{backends:?}"),
        })?;
        let info = adapter.get_info();
        if !allowed.contains(wgpu::Backends::from(info.backend)) {
            return Err(GpuError::NoAdapter {
                wanted: format!("{backends:?}, got {:?}", info.backend),
            });
        }
        let limits = adapter.limits();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("eikon"),
            required_features: wgpu::Features::empty(),
            // As large storage buffers as the adapter allows (128 MiB on
            // lavapipe); bigger volumes are split by the caller.
            required_limits: wgpu::Limits {
                max_storage_buffer_binding_size: limits.max_storage_buffer_binding_size,
                max_buffer_size: limits.max_buffer_size,
                max_compute_workgroups_per_dimension: limits.max_compute_workgroups_per_dimension,
                // The light simulator binds its patch lists, pyramids and
                // per-channel volumes at once (about 20 storage buffers)
                // and samples the medium from 3D textures.
                max_storage_buffers_per_shader_stage: limits.max_storage_buffers_per_shader_stage,
                max_texture_dimension_3d: limits.max_texture_dimension_3d,
                max_bind_groups: limits.max_bind_groups,
                ..wgpu::Limits::downlevel_defaults()
            },
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .map_err(|e| GpuError::Device {
            adapter: info.name.clone(),
            message: e.to_string(),
        })?;
        let uncaptured = Arc::new(Mutex::new(Vec::new()));
        let sink = uncaptured.clone();
        device.on_uncaptured_error(Box::new(move |e| {
            if let Ok(mut v) = sink.lock() {
                v.push(e.to_string());
            }
        }));
        Ok(Gpu {
            device,
            queue,
            info,
            uncaptured,
        })
    }

    /// A one-line description: adapter name and backend.
    pub fn describe(&self) -> String {
        format!(
            "{} ({:?}, {:?})",
            self.info.name, self.info.backend, self.info.device_type
        )
    }

    /// Run `f` inside a validation error scope: its wgpu errors come back
    /// as [`GpuError::Validation`] naming `what`.
    pub fn checked<T>(&self, what: &str, f: impl FnOnce() -> T) -> Result<T, GpuError> {
        self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let out = f();
        if let Some(e) = pollster::block_on(self.device.pop_error_scope()) {
            return Err(GpuError::Validation {
                what: what.to_string(),
                message: e.to_string(),
            });
        }
        if let Some(e) = self.uncaptured.lock().ok().and_then(|mut v| v.pop()) {
            return Err(GpuError::Validation {
                what: what.to_string(),
                message: e,
            });
        }
        Ok(out)
    }

    /// A compute pipeline from WGSL `source`, entry point `entry`.
    pub fn pipeline(
        &self,
        label: &str,
        source: &str,
        entry: &str,
    ) -> Result<wgpu::ComputePipeline, GpuError> {
        self.checked(label, || {
            let module = self
                .device
                .create_shader_module(wgpu::ShaderModuleDescriptor {
                    label: Some(label),
                    source: wgpu::ShaderSource::Wgsl(source.into()),
                });
            self.device
                .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(label),
                    layout: None,
                    module: &module,
                    entry_point: Some(entry),
                    compilation_options: Default::default(),
                    cache: None,
                })
        })
    }

    /// A bind group for group 0 of `pipeline`, binding `i` to
    /// `buffers[i]` whole.
    pub fn bind(
        &self,
        pipeline: &wgpu::ComputePipeline,
        buffers: &[&wgpu::Buffer],
    ) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry> = buffers
            .iter()
            .enumerate()
            .map(|(i, b)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: b.as_entire_binding(),
            })
            .collect();
        self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &pipeline.get_bind_group_layout(0),
            entries: &entries,
        })
    }

    /// A storage buffer holding `data` (also a copy source and target).
    pub fn storage<T: bytemuck::Pod>(&self, label: &str, data: &[T]) -> wgpu::Buffer {
        self.device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: bytemuck::cast_slice(data),
                usage: wgpu::BufferUsages::STORAGE
                    | wgpu::BufferUsages::COPY_SRC
                    | wgpu::BufferUsages::COPY_DST,
            })
    }

    /// An empty storage buffer of `bytes` (at least 4).
    pub fn storage_empty(&self, label: &str, bytes: u64) -> wgpu::Buffer {
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: bytes.max(4),
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    /// A uniform buffer holding `data`.
    pub fn uniform<T: bytemuck::Pod>(&self, label: &str, data: &[T]) -> wgpu::Buffer {
        self.device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: bytemuck::cast_slice(data),
                usage: wgpu::BufferUsages::UNIFORM,
            })
    }

    /// Copy `len` elements of `buffer` back to the CPU.
    pub fn read<T: bytemuck::Pod>(
        &self,
        buffer: &wgpu::Buffer,
        len: usize,
    ) -> Result<Vec<T>, GpuError> {
        let bytes = (len * std::mem::size_of::<T>()) as u64;
        if bytes == 0 {
            return Ok(Vec::new());
        }
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut enc = self.device.create_command_encoder(&Default::default());
        enc.copy_buffer_to_buffer(buffer, 0, &staging, 0, bytes);
        self.queue.submit([enc.finish()]);
        let slice = staging.slice(..);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.device
            .poll(wgpu::PollType::Wait)
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        rx.recv()
            .map_err(|e| GpuError::Readback(e.to_string()))?
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        let out = bytemuck::cast_slice(&slice.get_mapped_range()).to_vec();
        staging.unmap();
        Ok(out)
    }
}

/// Workgroup counts `(x, y)` covering `items` threads of [`WORKGROUP`] in
/// a 2-D dispatch (one dimension holds at most 65535 groups); a kernel
/// recovers its item as `id.x + id.y * num_workgroups.x * WORKGROUP`.
pub fn groups(items: usize) -> (u32, u32) {
    let g = (items as u64).div_ceil(WORKGROUP as u64).max(1);
    let x = g.min(65535);
    (x as u32, g.div_ceil(x) as u32)
}

/// The device for a test of a GPU backend, under the tests' policy: without
/// an adapter the test is skipped (`None`), except where the `CI`
/// environment variable is set (`.ci/run` sets it and installs lavapipe):
/// there a missing adapter fails the test. Under `WGPU_BACKEND=vulkan` the
/// adapter must be a Vulkan one.
pub fn test_device() -> Option<Gpu> {
    match Gpu::new() {
        Ok(g) => {
            println!("adapter: {}", g.describe());
            if std::env::var("WGPU_BACKEND").is_ok_and(|b| b.eq_ignore_ascii_case("vulkan")) {
                assert_eq!(g.info.backend, wgpu::Backend::Vulkan, "{}", g.describe());
            }
            Some(g)
        }
        Err(e) => {
            assert!(
                std::env::var_os("CI").is_none(),
                "CI must have a GPU adapter (lavapipe): {e}"
            );
            eprintln!("skipped (no GPU adapter here): {e}");
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dispatch_covers_every_item() {
        for n in [0usize, 1, 64, 65, 65535 * 64, 65535 * 64 + 1, 10_000_000] {
            let (x, y) = groups(n);
            assert!(x <= 65535 && y >= 1);
            assert!(x as u64 * y as u64 * WORKGROUP as u64 >= n as u64);
        }
    }
}
