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
//! * Every buffer and texture the backends create goes through [`Gpu`]'s
//!   helpers, which tally their bytes ([`Gpu::allocated_bytes`],
//!   [`Gpu::live_bytes`], [`Gpu::peak_bytes`]): the tests hold the
//!   backends' estimates of device memory (checked before a run) to what a
//!   run really creates.

pub mod layout;

use std::ops::Deref;
use std::sync::atomic::{AtomicU64, Ordering};
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
    /// The scene asks for something this GPU backend does not implement
    /// (the message says what, and what it supports).
    #[error("{0}")]
    Unsupported(String),
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
    tally: Arc<Tally>,
    /// The staging buffer of small reads ([`SMALL_READ`] bytes, made on
    /// the first): a simulation reads a word or two back per step, and a
    /// buffer made and freed per read costs a device allocation each time.
    small: Mutex<Option<wgpu::Buffer>>,
}

/// Reads up to this many bytes go through one staging buffer kept for the
/// device's life (outside the tally: its bytes are too few to move an
/// estimate), larger ones through a buffer of their size.
pub const SMALL_READ: u64 = 256;

/// Bytes of the buffers and textures made by [`Gpu`]'s helpers.
#[derive(Debug, Default)]
struct Tally {
    /// Ever created.
    created: AtomicU64,
    /// Created and not yet dropped.
    live: AtomicU64,
    /// Highest `live` since the device opened or [`Gpu::reset_peak`].
    peak: AtomicU64,
    /// Command submissions made through [`Gpu::submit`] and [`Gpu::read`].
    submissions: AtomicU64,
    /// Reads back to the CPU ([`Gpu::read`]): each waits for the GPU.
    readbacks: AtomicU64,
}

/// How often the CPU handed work to the GPU and waited for results, since
/// the device opened: what a run costs in round trips beside its time
/// (`eikon bench`). The difference of two readings counts one run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Traffic {
    /// Command submissions.
    pub submissions: u64,
    /// Reads back to the CPU, each a wait for the GPU to finish.
    pub readbacks: u64,
}

impl Tally {
    fn add(&self, bytes: u64) {
        self.created.fetch_add(bytes, Ordering::Relaxed);
        let now = self.live.fetch_add(bytes, Ordering::Relaxed) + bytes;
        self.peak.fetch_max(now, Ordering::Relaxed);
    }
}

/// A buffer made by [`Gpu`]'s helpers: a `wgpu::Buffer` (it derefs to one)
/// whose bytes leave [`Gpu::live_bytes`] when it is dropped, so the tally
/// follows what a run holds, not only what it ever made.
#[derive(Debug)]
pub struct Buffer {
    buffer: wgpu::Buffer,
    tally: Arc<Tally>,
}

impl Deref for Buffer {
    type Target = wgpu::Buffer;
    fn deref(&self) -> &wgpu::Buffer {
        &self.buffer
    }
}

impl Drop for Buffer {
    fn drop(&mut self) {
        self.tally
            .live
            .fetch_sub(self.buffer.size(), Ordering::Relaxed);
    }
}

/// A 3D texture made by [`Gpu::texture_3d`], with its default view (it
/// derefs to the `wgpu::Texture`); tallied as [`Buffer`] is.
#[derive(Debug)]
pub struct Texture {
    texture: wgpu::Texture,
    /// The whole texture, as the kernels bind it.
    pub view: wgpu::TextureView,
    bytes: u64,
    tally: Arc<Tally>,
}

impl Deref for Texture {
    type Target = wgpu::Texture;
    fn deref(&self) -> &wgpu::Texture {
        &self.texture
    }
}

impl Drop for Texture {
    fn drop(&mut self) {
        self.tally.live.fetch_sub(self.bytes, Ordering::Relaxed);
    }
}

/// Smallest buffer the helpers make, bytes (wgpu refuses empty buffers):
/// estimates of device memory count an empty array as this much.
pub const MIN_BUFFER_BYTES: u64 = 4;

/// Bytes of a `dims` (grid x, y, z) 3D texture of `format`: texels times
/// the texel size, as [`Gpu::texture_3d`] tallies it (a driver may pad
/// rows or tiles on top). Shared by the tally and the estimates.
pub fn texture_bytes(dims: [usize; 3], format: wgpu::TextureFormat) -> u64 {
    let texel = u64::from(format.block_copy_size(None).expect("a colour format"));
    dims.iter().map(|&d| d as u64).product::<u64>() * texel
}

/// Threads per workgroup of every eikon kernel (1-D).
pub const WORKGROUP: u32 = 64;

impl Gpu {
    /// Open the best Vulkan, Metal or DX12 adapter (never OpenGL), as
    /// narrowed by `WGPU_BACKEND`.
    pub fn new() -> Result<Gpu, GpuError> {
        // One device opens at a time in a process: NVIDIA's Linux driver
        // races when instances are created on several threads at once
        // (wgpu issue #5930; the optics crate's WGSL tests, two devices
        // opening at once, hung on an H100 in two runs of three).
        static OPENING: Mutex<()> = Mutex::new(());
        let _one = OPENING.lock().unwrap_or_else(|e| e.into_inner());
        let allowed = wgpu::Backends::VULKAN | wgpu::Backends::METAL | wgpu::Backends::DX12;
        let backends = wgpu::Backends::from_env().map_or(allowed, |b| b & allowed);
        // wgpu checks every indirect dispatch's sizes with a dispatch of
        // its own (and memory per dispatch) before it runs: the light
        // simulator's steps, all indirect, ran up to 1.8x slower with it on
        // lavapipe. The kernels that write those sizes (`plan_args` in
        // the simulator) keep them within the device's limits themselves.
        // `WGPU_VALIDATION_INDIRECT_CALL=1` turns the check back on.
        let flags = (wgpu::InstanceFlags::default()
            - wgpu::InstanceFlags::VALIDATION_INDIRECT_CALL)
            .with_env();
        let instance = wgpu::Instance::new(&wgpu::InstanceDescriptor {
            backends,
            flags,
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
                // Render targets as large as images may be (eikon-wyman).
                max_texture_dimension_2d: limits.max_texture_dimension_2d,
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
            tally: Arc::default(),
            small: Mutex::new(None),
        })
    }

    /// Bytes of every buffer and texture ever created through these
    /// helpers (dropped ones included): what a run made in all.
    pub fn allocated_bytes(&self) -> u64 {
        self.tally.created.load(Ordering::Relaxed)
    }

    /// Bytes of the helpers' buffers and textures not yet dropped (wgpu
    /// frees one's memory once its last bind group and submission are done
    /// with it as well; the backends drop those together).
    pub fn live_bytes(&self) -> u64 {
        self.tally.live.load(Ordering::Relaxed)
    }

    /// The most [`Self::live_bytes`] since the device opened or the last
    /// [`Self::reset_peak`]: the device memory a run needed at its peak,
    /// which the backends' `device_bytes` estimates must cover. Not
    /// counted: wgpu's own transient staging for `write_buffer` and
    /// `write_texture` (at most one upload's bytes, freed once submitted)
    /// and drivers' padding.
    pub fn peak_bytes(&self) -> u64 {
        self.tally.peak.load(Ordering::Relaxed)
    }

    /// Submissions and readbacks so far ([`Traffic`]).
    pub fn traffic(&self) -> Traffic {
        Traffic {
            submissions: self.tally.submissions.load(Ordering::Relaxed),
            readbacks: self.tally.readbacks.load(Ordering::Relaxed),
        }
    }

    /// Submit command buffers to the queue, counted ([`Gpu::traffic`]).
    pub fn submit(&self, commands: impl IntoIterator<Item = wgpu::CommandBuffer>) {
        self.tally.submissions.fetch_add(1, Ordering::Relaxed);
        self.queue.submit(commands);
    }

    /// Start a new peak from what is live now (before measuring a run).
    pub fn reset_peak(&self) {
        self.tally
            .peak
            .store(self.tally.live.load(Ordering::Relaxed), Ordering::Relaxed);
    }

    /// Tally `buffer`.
    fn track(&self, buffer: wgpu::Buffer) -> Buffer {
        self.tally.add(buffer.size());
        Buffer {
            buffer,
            tally: self.tally.clone(),
        }
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
    pub fn bind(&self, pipeline: &wgpu::ComputePipeline, buffers: &[&Buffer]) -> wgpu::BindGroup {
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
    pub fn storage<T: bytemuck::Pod>(&self, label: &str, data: &[T]) -> Buffer {
        self.track(
            self.device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some(label),
                    contents: bytemuck::cast_slice(data),
                    usage: wgpu::BufferUsages::STORAGE
                        | wgpu::BufferUsages::COPY_SRC
                        | wgpu::BufferUsages::COPY_DST,
                }),
        )
    }

    /// An empty storage buffer of `bytes` (at least [`MIN_BUFFER_BYTES`]).
    pub fn storage_empty(&self, label: &str, bytes: u64) -> Buffer {
        self.empty(label, bytes, wgpu::BufferUsages::empty())
    }

    /// An empty storage buffer of `bytes` that also holds the arguments of
    /// indirect dispatches: kernels write how many workgroups later
    /// kernels of the same submission run (a copy source and target too).
    pub fn storage_indirect(&self, label: &str, bytes: u64) -> Buffer {
        self.empty(label, bytes, wgpu::BufferUsages::INDIRECT)
    }

    /// An empty storage buffer (a copy source and target) with `usage`
    /// besides, tallied.
    fn empty(&self, label: &str, bytes: u64, usage: wgpu::BufferUsages) -> Buffer {
        self.track(self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: bytes.max(MIN_BUFFER_BYTES),
            usage: usage
                | wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        }))
    }

    /// A small read-only buffer of parameters holding `data` (also a copy
    /// target, to be rewritten with `queue.write_buffer`), which kernels
    /// bind as `var<storage, read>`, not as a uniform block: lavapipe
    /// (Mesa 22.3) inlines the values of a uniform block that feed loop
    /// conditions and, where that shrinks the kernel enough, re-optimizes
    /// the kernel at every dispatch and keeps each variant: the light
    /// simulator's steps then cost far more than their kernels, and host
    /// memory grew by the step (docs/PERFORMANCE.md, "lavapipe's
    /// per-dispatch cost").
    pub fn params<T: bytemuck::Pod>(&self, label: &str, data: &[T]) -> Buffer {
        self.block(
            label,
            bytemuck::cast_slice(data),
            wgpu::BufferUsages::STORAGE,
        )
    }

    /// A uniform buffer holding `data` (also a copy target). lavapipe
    /// specializes a kernel to the values of its uniform block where that
    /// shrinks it; the view renderer, which dispatches its kernel a few
    /// times a frame, runs several times faster for it (docs/PERFORMANCE.md,
    /// "lavapipe's per-dispatch cost"), and render pipelines' vertex stages
    /// may not read storage buffers.
    /// Kernels dispatched many times with changing values take
    /// [`Gpu::params`].
    pub fn uniform<T: bytemuck::Pod>(&self, label: &str, data: &[T]) -> Buffer {
        self.block(
            label,
            bytemuck::cast_slice(data),
            wgpu::BufferUsages::UNIFORM,
        )
    }

    /// A buffer of `usage` (and a copy target) holding `bytes`.
    fn block(&self, label: &str, bytes: &[u8], usage: wgpu::BufferUsages) -> Buffer {
        self.track(
            self.device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some(label),
                    contents: bytes,
                    usage: usage | wgpu::BufferUsages::COPY_DST,
                }),
        )
    }

    /// A `dims` (grid x, y, z) 3D texture of `format` sampled by the
    /// kernels, whose cell `(i, j, k)` sits at texel `(k, j, i)`, filled
    /// by `slab(i0, i1)` with the bytes of grid slabs `i0..i1` (C order).
    /// Slabs of about 16 MiB keep wgpu's staging copies small.
    pub fn texture_3d(
        &self,
        label: &str,
        dims: [usize; 3],
        format: wgpu::TextureFormat,
        slab: &dyn Fn(usize, usize) -> Vec<u8>,
    ) -> Texture {
        let [nx, ny, nz] = dims;
        let texture = self.device.create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size: wgpu::Extent3d {
                width: nz as u32,
                height: ny as u32,
                depth_or_array_layers: nx as u32,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D3,
            format,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        let bytes = texture_bytes(dims, format);
        self.tally.add(bytes);
        let texel = format.block_copy_size(None).expect("a colour format") as usize;
        let per = (16usize << 20) / (ny * nz * texel).max(1);
        let per = per.clamp(1, nx.max(1));
        let mut i0 = 0;
        while i0 < nx {
            let i1 = (i0 + per).min(nx);
            let data = slab(i0, i1);
            self.queue.write_texture(
                wgpu::TexelCopyTextureInfo {
                    texture: &texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d {
                        x: 0,
                        y: 0,
                        z: i0 as u32,
                    },
                    aspect: wgpu::TextureAspect::All,
                },
                &data,
                wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some((nz * texel) as u32),
                    rows_per_image: Some(ny as u32),
                },
                wgpu::Extent3d {
                    width: nz as u32,
                    height: ny as u32,
                    depth_or_array_layers: (i1 - i0) as u32,
                },
            );
            i0 = i1;
        }
        Texture {
            view: texture.create_view(&Default::default()),
            texture,
            bytes,
            tally: self.tally.clone(),
        }
    }

    /// A `width` x `height` 2D texture of `format` with `usage` (render
    /// targets, depth buffers), tallied as [`Gpu::texture_3d`]'s are.
    pub fn texture_2d(
        &self,
        label: &str,
        [width, height]: [u32; 2],
        format: wgpu::TextureFormat,
        usage: wgpu::TextureUsages,
    ) -> Texture {
        let texture = self.device.create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size: wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage,
            view_formats: &[],
        });
        let texel = format.block_copy_size(None).unwrap_or(4);
        let bytes = u64::from(width) * u64::from(height) * u64::from(texel);
        self.tally.add(bytes);
        Texture {
            view: texture.create_view(&Default::default()),
            texture,
            bytes,
            tally: self.tally.clone(),
        }
    }

    /// Copy `len` elements of `buffer` back to the CPU. Up to
    /// [`SMALL_READ`] bytes go through the device's small staging buffer;
    /// more through a staging buffer of their size that is tallied while
    /// the read lasts (it is dropped before this returns: it counts
    /// towards [`Self::peak_bytes`], not [`Self::live_bytes`] after).
    pub fn read<T: bytemuck::Pod>(
        &self,
        buffer: &wgpu::Buffer,
        len: usize,
    ) -> Result<Vec<T>, GpuError> {
        let bytes = (len * std::mem::size_of::<T>()) as u64;
        if bytes == 0 {
            return Ok(Vec::new());
        }
        if bytes <= SMALL_READ {
            let mut small = self
                .small
                .lock()
                .map_err(|e| GpuError::Readback(e.to_string()))?;
            let staging = small.get_or_insert_with(|| {
                self.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("small readback"),
                    size: SMALL_READ,
                    usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                })
            });
            let out = self.read_through(buffer, staging, bytes);
            if out.is_err() {
                // It may be left mapped: the next small read makes another.
                *small = None;
            }
            return out;
        }
        let staging = self.track(self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        }));
        self.read_through(buffer, &staging, bytes)
    }

    /// The first `bytes` of `buffer`, copied into `staging`, waited for
    /// and mapped.
    fn read_through<T: bytemuck::Pod>(
        &self,
        buffer: &wgpu::Buffer,
        staging: &wgpu::Buffer,
        bytes: u64,
    ) -> Result<Vec<T>, GpuError> {
        let mut enc = self.device.create_command_encoder(&Default::default());
        enc.copy_buffer_to_buffer(buffer, 0, staging, 0, bytes);
        self.tally.readbacks.fetch_add(1, Ordering::Relaxed);
        self.submit([enc.finish()]);
        let slice = staging.slice(..bytes);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.wait()?;
        rx.recv()
            .map_err(|e| GpuError::Readback(e.to_string()))?
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        let out = bytemuck::cast_slice(&slice.get_mapped_range()).to_vec();
        staging.unmap();
        Ok(out)
    }
}

/// How long [`Gpu::wait`] waits for the GPU in all. wgpu gives up on one
/// wait after a minute; lavapipe (llvmpipe) compiles a kernel when a
/// submission first dispatches it, not when the pipeline is made, and cold
/// (no shader cache) the view renderer's kernel with every sharp shape and
/// VDB grids took longer than that. A hardware GPU's driver ends a
/// submission long before this.
const MOST_WAIT: std::time::Duration = std::time::Duration::from_secs(1800);

impl Gpu {
    /// Block until everything submitted has run, waiting again where one
    /// of wgpu's waits times out, for up to [`MOST_WAIT`] in all.
    pub fn wait(&self) -> Result<(), GpuError> {
        let start = std::time::Instant::now();
        loop {
            match self.device.poll(wgpu::PollType::Wait) {
                Ok(_) => return Ok(()),
                Err(wgpu::PollError::Timeout) if start.elapsed() < MOST_WAIT => {}
                Err(e) => return Err(GpuError::Readback(e.to_string())),
            }
        }
    }

    /// Compile `entry` of the WGSL `source` as an [`Eval`] kernel.
    pub fn eval_kernel(&self, source: &str, entry: &str) -> Result<Eval, GpuError> {
        Ok(Eval {
            pipeline: self.pipeline(entry, source, entry)?,
            entry: entry.to_string(),
        })
    }

    /// [`Eval::run`] of `entry` in `source`, compiled for this one call.
    pub fn eval(
        &self,
        source: &str,
        entry: &str,
        inputs: &[[f32; 4]],
        per_input: usize,
        extra: &[wgpu::BindingResource],
    ) -> Result<Vec<[f32; 4]>, GpuError> {
        self.eval_kernel(source, entry)?
            .run(self, inputs, per_input, extra)
    }
}

/// A kernel that evaluates shared WGSL functions on a batch of arguments
/// (the function-level parity tests), one thread per input.
pub struct Eval {
    pipeline: wgpu::ComputePipeline,
    entry: String,
}

impl Eval {
    /// Run the kernel once per element of `inputs` and read its output
    /// back. It sees `@group(0) @binding(0) var<storage, read> input:
    /// array<vec4<f32>>` (integers passed as their bits), `@binding(1)
    /// var<storage, read_write> output: array<vec4<f32>>` (`per_input`
    /// entries per input; the entry point must use both) and `extra[i]` at
    /// binding `2 + i`; the threads are numbered as [`groups`] lays them
    /// out (the `dispatch` module's `item`).
    pub fn run(
        &self,
        gpu: &Gpu,
        inputs: &[[f32; 4]],
        per_input: usize,
        extra: &[wgpu::BindingResource],
    ) -> Result<Vec<[f32; 4]>, GpuError> {
        let input = gpu.storage("eval input", inputs);
        let len = inputs.len() * per_input;
        let output = gpu.storage_empty("eval output", (len * 16) as u64);
        gpu.checked(&self.entry, || {
            let mut entries = vec![
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: input.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: output.as_entire_binding(),
                },
            ];
            for (i, r) in extra.iter().enumerate() {
                entries.push(wgpu::BindGroupEntry {
                    binding: 2 + i as u32,
                    resource: r.clone(),
                });
            }
            let bind = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some(&self.entry),
                layout: &self.pipeline.get_bind_group_layout(0),
                entries: &entries,
            });
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            {
                let mut pass = enc.begin_compute_pass(&Default::default());
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, &bind, &[]);
                let (x, y) = groups(inputs.len());
                pass.dispatch_workgroups(x, y, 1);
            }
            gpu.submit([enc.finish()]);
        })?;
        gpu.read(&output, len)
    }
}

/// The workgroup size and how a kernel numbers its threads, as [`groups`]
/// dispatches them: `item(id, groups)` is the thread's item.
pub static DISPATCH: eikon_shader::Module = eikon_shader::Module {
    name: "dispatch",
    requires: &[],
    declarations: dispatch_declarations,
    text: "fn item(id: vec3<u32>, groups: vec3<u32>) -> u32 {\n    return id.x + id.y * groups.x * WORKGROUP;\n}\n",
};

fn dispatch_declarations() -> String {
    eikon_shader::Consts::new()
        .u32("WORKGROUP", WORKGROUP)
        .wgsl()
        .to_string()
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
