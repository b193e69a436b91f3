//! The light simulator on the GPU: every step of [`crate::simulate_light`]
//! as wgpu compute kernels (`simulate.wgsl`), with the same physics,
//! conventions and units, in f32, for both deposit rules
//! ([`DepositRule`]) and with or without Fresnel transmission.
//!
//! Per wavefront, emission (`light::emit`), the absorption inside a
//! point light's start sphere (and, with the fluence deposit, the chords
//! from the light to its start sphere) and the pre-step tessellation run on
//! the CPU exactly as there; the patches are then uploaded and every step
//! runs on the GPU: propagate (eqs 14-15, 18, Fresnel at interfaces) with,
//! for the fluence deposit, the tube each patch sweeps deposited in the
//! same kernel (`deposit::tube`: sub-patches, box footprints, chords cut
//! among the cells by a 3D DDA, summed per cell in a small per-thread
//! cache), tessellation analysis (`refine::fate`, the deposit's own
//! rules: caustics culled with the paper's only, exit when every corner
//! has left, faint and dim patches), the split grants (in patch order, by
//! the rank of each split read off a HistoPyramid of the split flags), the
//! HistoPyramid of the counts and its walk (compaction and expansion in one
//! pass), and, with the paper's deposit, the highest-energy rule (atomics
//! on packed keys, ties to the lowest patch index as the CPU's in-order
//! apply) and the irradiance of eq 17. The only read-back per step is the
//! new list's length.
//!
//! The fluence deposit adds to 64-bit fixed-point counters as
//! [`Counters`] does (fluence per cell and channel, the flux vector per
//! cell, component and wavefront group in two's complement; the same
//! scales), each as two u32 words added with a carry; the energy tallies
//! (absorbed, exited, culled, reflected, trapped) are 64-bit fixed point the same
//! way. Integer addition commutes, so neither depends on the order the
//! threads run in: the volumes and the summary are the same bit for bit
//! from run to run. At the end the words are read back and added to the
//! CPU's counters (which hold the start sphere's chords), and
//! [`Counters::into_volume`] converts them as on the CPU.
//!
//! # Memory
//! The index field (with its gradient), the extinction and, with Fresnel,
//! the interface sides with the boundary indicator (one per index channel,
//! uploaded with the first simulation that asks for it) are rgba32float 3D
//! textures (no storage binding limit; 16 bytes per cell each). The light
//! volume is one storage buffer of one word per cell (`4 nx ny nz` bytes)
//! for each array: with the fluence deposit twelve (the low and the high
//! words of three fluence channels and of three flux-vector components, 48
//! bytes per cell; the flux words are read back and cleared per wavefront
//! group), with the paper's nine (keys, stamps, owners, irradiance and
//! direction, 36 bytes per cell). So a 256^3 volume (64 MiB per buffer, 768
//! MiB for the fluence counters, 256 MiB per texture) fits lavapipe's 128
//! MiB binding limit. The patch lists grow as needed up to that limit (64
//! bytes of corner positions per patch: 2M patches at 128 MiB);
//! `max_patches` is lowered to what fits, and anything that still does not
//! fit is a [`GpuError::TooLarge`]. [`GpuSimulator::device_bytes`]
//! estimates the peak from these layouts before a run; the lists are
//! sized by `max_patches`, which the grants keep them under.
//!
//! # Differences from the CPU
//! * f32 throughout the steps and the deposit (the CPU works in f64;
//!   emission and the pre-step tessellation are the CPU's, rounded once on
//!   upload, and the start sphere's chords the CPU's own units). Patches
//!   at a tessellation threshold or, with the paper's deposit, at a
//!   caustic can take the other fate, and the lists drift apart where the
//!   light field is multi-valued. With the fluence deposit every cell sums
//!   many patches, so a different tessellation moves its value a little:
//!   on the glass sphere (24^3, Fresnel) the median relative fluence
//!   difference is 5e-4 for a directional light, whose lists part behind
//!   the sphere, and 2e-6 for the point and spot lights, whose lists stay
//!   the same (numbers in `tests/gpu.rs`; 1.7e-3 at 128^3). With the
//!   paper's deposit a cell holds one ray: median relative irradiance
//!   difference 1.2e-7 on the 128^3 glass sphere, 98.8% of the cells
//!   within 1%, lists peaking at 64.6k patches against the CPU's 65.3k.
//! * A piece of a chord is summed in f32 before it is rounded to units
//!   (the CPU: f64), which moves a cell's counter by about 1e-7 of itself;
//!   `1 - exp(-x)` is a series below x = 0.01 (the CPU: `exp_m1`).
//! * Corners 1 to 3 are stored relative to corner 0, and each step moves
//!   them by the difference of their displacements: f32 rounding of the
//!   absolute positions (about 1e-5 of a voxel per step at 128^3) would
//!   otherwise wear the patches' shapes away and split a plane wave's
//!   patches at random. For what rounding is left, a patch is tessellated
//!   when its span exceeds the split size by more than 1e-5 (the CPU:
//!   1e-9).
//! * Energy tallies are exact sums of the f32 fluxes (64-bit fixed point at
//!   2^-52 of the largest channel's power); the balance holds to about
//!   1e-8 instead of 1e-15.
//! * On a software adapter (lavapipe) the fluence deposit is several times
//!   slower than the CPU backend: one thread per patch with a varying
//!   number of chords diverges on its SIMD lanes.

use crate::deposit::Counters;
use crate::patch::Patches;
use crate::refine::Incident;
use crate::{crossings_bound, power_bound, units_per_crossing, DepositRule, Summary};
use crate::{propagate, refine, Error, LightVolume, Options};
use eikon_gpu::{groups, texture_bytes, Buffer, Gpu, GpuError, Texture, MIN_BUFFER_BYTES};
use eikon_grid::blocks::BLOCK;
use eikon_grid::interface::{probe_length, Interfaces};
use eikon_grid::{EmptySpace, Integrator, Light, Medium, Progress};
use glam::DVec3;
use ndarray::Array4;
use std::sync::OnceLock;

const SOURCE: &str = include_str!("simulate.wgsl");

/// Bytes per patch of a list's arrays (see [`PatchSet`]): four corner
/// positions with their optical path lengths, four gradients, and the
/// flux, initial flux and irradiance (with area and depth).
const POS_BYTES: u64 = 64;
const VEL_BYTES: u64 = 64;
const AUX_BYTES: u64 = 48;
/// Bytes of the largest per-patch array (four corner positions).
const PATCH_BYTES: u64 = POS_BYTES;
/// Bytes per patch of the paper's deposit's scratch: each patch's five
/// deposits of a step.
const DEPOSIT_BYTES: u64 = 40;
/// Smallest capacity of the patch lists (grown by doubling from there).
const FIRST_CAP: usize = 4096;
/// Format of the medium's textures.
const TEXEL: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;
/// Storage buffers bound at once (groups 0 to 2 of `simulate.wgsl`).
const STORAGE_BUFFERS: u32 = 24;
/// Most pyramid levels (4^15 entries).
const MAX_LEVELS: usize = 16;

const KERNELS: [&str; 14] = [
    "propagate",
    "analyse",
    "reduce_splits",
    "grant",
    "reduce_counts",
    "expand",
    "mid_max",
    "mid_owner",
    "mid_write",
    "corner_max",
    "corner_owner",
    "corner_write",
    "cull_rest",
    "propagate_tube",
];
const PROPAGATE: usize = 0;
const ANALYSE: usize = 1;
const REDUCE_SPLITS: usize = 2;
const GRANT: usize = 3;
const REDUCE_COUNTS: usize = 4;
const EXPAND: usize = 5;
const DEPOSIT: usize = 6; // six kernels: midpoints (3 passes), corners (3)
const CULL_REST: usize = 12;
const PROPAGATE_TUBE: usize = 13;

/// Stats words (see `simulate.wgsl`): five energy categories (absorbed,
/// exited, culled, reflected, trapped) per channel in 64-bit fixed point,
/// then counts.
const STATS_WORDS: usize = 37;
const S_EXITED: usize = 30;
const S_ABSORBED: usize = 31;
const S_CAUSTIC: usize = 32;
const S_HELD: usize = 33;
const S_KEPT: u64 = 34;
const S_FAINT: usize = 36;

/// Storage buffers of the light volume (group 2): the paper's deposit
/// binds 9 of them, the fluence deposit's counters all 12.
const VOLUME_BUFFERS: usize = 12;
const PAPER_VOLUME_BUFFERS: usize = 9;

/// Simulate one light on the GPU: [`crate::simulate_light`]'s result
/// computed by [`GpuSimulator`] (which uploads `medium` first).
pub fn simulate_light(
    gpu: &Gpu,
    light: &Light,
    medium: &Medium,
    opts: &Options,
    progress: Progress,
) -> Result<(LightVolume, Summary), Error> {
    GpuSimulator::new(gpu, medium)?.simulate(light, opts, progress)
}

/// One medium uploaded to the GPU with the simulator's kernels, to light
/// it with any number of lights.
pub struct GpuSimulator<'a> {
    gpu: &'a Gpu,
    medium: &'a Medium,
    layouts: [wgpu::BindGroupLayout; 4],
    kernels: Vec<wgpu::ComputePipeline>,
    /// Per index channel: its texture and empty-space table.
    index: Vec<(Texture, Buffer)>,
    extinction: Texture,
    /// Per index channel, the interface sides and the boundary indicator
    /// for Fresnel, `(n_lo, n_hi, delta, 0)` per cell: uploaded with the
    /// first simulation that asks for Fresnel.
    fresnel: OnceLock<Vec<Texture>>,
    /// Bound in place of those without Fresnel.
    no_fresnel: Texture,
    /// Largest storage binding, bytes.
    binding_limit: u64,
    /// Blocks of the empty-space tables and their inverse size.
    empty_dims: [u32; 3],
    inv_block: DVec3,
}

fn storage_entry(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

fn uniform_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

fn texture_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable: false },
            view_dimension: wgpu::TextureViewDimension::D3,
            multisampled: false,
        },
        count: None,
    }
}

fn too_large(what: &str, need: u64, limit: u64, hint: &str) -> GpuError {
    GpuError::TooLarge {
        what: what.to_string(),
        need,
        limit,
        hint: hint.to_string(),
    }
}

/// Upload a `(nx, ny, nz, 4)` f32 array as an rgba32float 3D texture of
/// texel `(k, j, i)` for cell `(i, j, k)`.
fn texture(gpu: &Gpu, label: &str, dims: [usize; 3], data: &[f32]) -> Texture {
    let slab = dims[1] * dims[2] * 4;
    gpu.texture_3d(label, dims, TEXEL, &|i0, i1| {
        bytemuck::cast_slice(&data[i0 * slab..i1 * slab]).to_vec()
    })
}

/// The uniform index of every empty block, or -1 (`EmptySpace`'s table,
/// read through its public lookup at each block's centre).
fn empty_table(medium: &Medium, channel: usize) -> (Vec<f32>, [u32; 3], DVec3) {
    let empty = EmptySpace::new(medium, channel);
    let blocks = empty.blocks();
    let out = (0..blocks.len())
        .map(|f| {
            let c = blocks.centre(blocks.coords(f));
            empty.index_at(c).map_or(-1.0, |n| n as f32)
        })
        .collect();
    (out, blocks.dims.map(|d| d as u32), blocks.inv_edge())
}

/// Growable GPU patch list.
struct PatchSet {
    cap: usize,
    pos: Buffer,
    vel: Buffer,
    aux: Buffer,
}

impl PatchSet {
    fn new(gpu: &Gpu, cap: usize) -> Self {
        let cap = cap.max(1) as u64;
        Self {
            cap: cap as usize,
            pos: gpu.storage_empty("patch positions", cap * POS_BYTES),
            vel: gpu.storage_empty("patch gradients", cap * VEL_BYTES),
            aux: gpu.storage_empty("patch flux", cap * AUX_BYTES),
        }
    }

    /// Device bytes of a list of `cap` patches.
    fn bytes(cap: usize) -> u64 {
        cap.max(1) as u64 * (POS_BYTES + VEL_BYTES + AUX_BYTES)
    }
}

/// Bytes of the per-patch scratch over `n` patches: the pyramids of the
/// counts and of the split flags, the fates, and each patch's deposits
/// (`dep_bytes` per patch).
fn scratch_bytes(n: usize, dep_bytes: u64) -> [u64; 4] {
    let pyramid = pyramid_size(n) as u64 * 4;
    [pyramid, pyramid, n as u64 * 4, n as u64 * dep_bytes]
}

/// Entries of a pyramid over `n` entries (all levels).
fn pyramid_size(n: usize) -> usize {
    let mut len = n.max(1);
    let mut total = len;
    while len > 1 {
        len = len.div_ceil(4);
        total += len;
    }
    total
}

fn pyramid_levels(n: usize) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut len = n.max(1);
    let mut off = 0;
    loop {
        out.push((off, len));
        if len == 1 {
            return out;
        }
        off += len;
        len = len.div_ceil(4);
    }
}

/// Dispatch `kernel` over `items` threads.
fn dispatch(pass: &mut wgpu::ComputePass, k: &wgpu::ComputePipeline, items: usize) {
    if items == 0 {
        return;
    }
    pass.set_pipeline(k);
    let (x, y) = groups(items);
    pass.dispatch_workgroups(x, y, 1);
}

/// Words of the uniform block of `simulate.wgsl` (`Params`).
const PARAMS_WORDS: usize = 64;

/// The uniform block of `simulate.wgsl` (`Params`).
#[derive(Clone, Copy)]
struct Params([u32; PARAMS_WORDS]);

impl Params {
    fn f(&mut self, at: usize, v: f64) {
        self.0[at] = (v as f32).to_bits();
    }
    fn v(&mut self, at: usize, v: DVec3) {
        self.f(at, v.x);
        self.f(at + 1, v.y);
        self.f(at + 2, v.z);
    }
    fn set_n(&mut self, n: usize, n_old: usize) {
        self.0[3] = n as u32;
        self.0[7] = n_old as u32;
    }
}

impl<'a> GpuSimulator<'a> {
    /// Compile the kernels and upload `medium` (its index channels and
    /// extinction as 3D textures, its empty-space tables).
    pub fn new(gpu: &'a Gpu, medium: &'a Medium) -> Result<Self, GpuError> {
        let limit = gpu.device.limits().max_storage_buffer_binding_size as u64;
        Self::with_binding_limit(gpu, medium, limit)
    }

    /// [`Self::new`] with storage bindings limited to `limit` bytes (at
    /// most the device's): to exercise the splitting of large volumes on
    /// small inputs.
    pub fn with_binding_limit(
        gpu: &'a Gpu,
        medium: &'a Medium,
        limit: u64,
    ) -> Result<Self, GpuError> {
        let limits = gpu.device.limits();
        let binding_limit = limit
            .min(limits.max_storage_buffer_binding_size as u64)
            .min(limits.max_buffer_size);
        if limits.max_storage_buffers_per_shader_stage < STORAGE_BUFFERS {
            return Err(too_large(
                "the light simulator's kernels (storage buffers per stage)",
                STORAGE_BUFFERS as u64,
                limits.max_storage_buffers_per_shader_stage as u64,
                "use --backend cpu",
            ));
        }
        let g = &medium.geometry;
        let max_dim = g.dims.iter().copied().max().unwrap_or(1) as u64;
        if max_dim > limits.max_texture_dimension_3d as u64 {
            return Err(too_large(
                "the medium's 3D textures (cells along an axis)",
                max_dim,
                limits.max_texture_dimension_3d as u64,
                "lower [grid] resolution or use --backend cpu",
            ));
        }
        let volume = g.voxel_count() as u64 * 4;
        if volume > binding_limit {
            return Err(too_large(
                "one channel of the light volume (bytes)",
                volume,
                binding_limit,
                "lower [grid] resolution or use --backend cpu",
            ));
        }
        let layouts = gpu.checked("light simulator layouts", || {
            let make = |label, entries: &[wgpu::BindGroupLayoutEntry]| {
                gpu.device
                    .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                        label: Some(label),
                        entries,
                    })
            };
            let mut g0 = vec![uniform_entry(0), texture_entry(1), texture_entry(2)];
            g0.push(storage_entry(3, true));
            g0.extend((4..9).map(|b| storage_entry(b, false)));
            g0.push(texture_entry(9));
            let g1: Vec<_> = (0..6).map(|b| storage_entry(b, false)).collect();
            let g2: Vec<_> = (0..VOLUME_BUFFERS as u32)
                .map(|b| storage_entry(b, false))
                .collect();
            [
                make("simulator medium", &g0),
                make("simulator patches", &g1),
                make("simulator volume", &g2),
                make("simulator level", &[uniform_entry(0)]),
            ]
        })?;
        let kernels = gpu.checked("light simulator kernels", || {
            let module = gpu
                .device
                .create_shader_module(wgpu::ShaderModuleDescriptor {
                    label: Some("simulate.wgsl"),
                    source: wgpu::ShaderSource::Wgsl(SOURCE.into()),
                });
            let layout = gpu
                .device
                .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                    label: Some("simulator"),
                    bind_group_layouts: &[&layouts[0], &layouts[1], &layouts[2], &layouts[3]],
                    push_constant_ranges: &[],
                });
            KERNELS
                .iter()
                .map(|entry| {
                    gpu.device
                        .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                            label: Some(entry),
                            layout: Some(&layout),
                            module: &module,
                            entry_point: Some(entry),
                            compilation_options: Default::default(),
                            cache: None,
                        })
                })
                .collect::<Vec<_>>()
        })?;
        let (_, empty_dims, inv_block) = empty_table(medium, 0);
        let (index, extinction, no_fresnel) = gpu.checked("uploading the medium", || {
            let index = (0..medium.channels())
                .map(|c| {
                    let data = medium.index[c].as_slice().expect("contiguous");
                    let view = texture(gpu, "index field", g.dims, data);
                    let (table, _, _) = empty_table(medium, c);
                    (view, gpu.storage("empty space", &table))
                })
                .collect::<Vec<_>>();
            let ext = medium.extinction.as_slice().expect("contiguous");
            let mut rgba = vec![0f32; g.voxel_count() * 4];
            for (o, e) in rgba.chunks_exact_mut(4).zip(ext.chunks_exact(3)) {
                o[..3].copy_from_slice(e);
            }
            let none = texture(gpu, "no interfaces", [1, 1, 1], &[0.0; 4]);
            (index, texture(gpu, "extinction", g.dims, &rgba), none)
        })?;
        Ok(Self {
            gpu,
            medium,
            layouts,
            kernels,
            index,
            extinction,
            fresnel: OnceLock::new(),
            no_fresnel,
            binding_limit,
            empty_dims,
            inv_block,
        })
    }

    /// Most patches the lists can hold.
    pub fn patch_limit(&self) -> usize {
        (self.binding_limit / PATCH_BYTES) as usize
    }

    /// Device memory, bytes, that [`Self::new`] and then [`Self::simulate`]
    /// of any one light with `opts` hold at their peak, for a medium of
    /// `dims` cells with `channels` index channels (3 with dispersion, else
    /// 1): an upper bound of what [`Gpu::peak_bytes`] counts over them, so
    /// that a run that does not fit the device can be refused before it
    /// starts. From the layouts the code allocates with, item by item:
    ///
    /// * the medium: per index channel an rgba32float texture and an
    ///   empty-space table (one f32 per block), the extinction texture and
    ///   the one-texel stand-in for the interfaces;
    /// * with `opts.fresnel`, the interface sides, one texture per channel
    ///   (kept by the simulator for later lights);
    /// * the light volume: one u32 per cell for each of its 12 arrays
    ///   (fluence deposit) or 9 (paper's, 3 unused placeholders);
    /// * the uniforms (parameters, one per pyramid level), the stats and
    ///   the word the list's length is read from;
    /// * the two patch lists at `opts.max_patches` (the grants never let a
    ///   list grow past it; the device may lower it to
    ///   [`Self::patch_limit`], which only lowers the need);
    /// * the per-patch scratch at that cap: two pyramids, the fates and,
    ///   with the paper's deposit, the deposits;
    /// * the largest transient: the old scratch while it is copied into a
    ///   larger one, or the staging buffer one volume array is read back
    ///   through.
    ///
    /// A wavefront emitted larger than `opts.max_patches` (emission checks
    /// only that it stays under `EMIT_PER_PATCH_LIMIT` times it) sizes the
    /// lists itself and is not covered. Not counted either: wgpu's own
    /// staging of uploads (at most one upload, freed once submitted) and
    /// drivers' padding.
    pub fn device_bytes(dims: [usize; 3], channels: usize, opts: &Options) -> u64 {
        let cells = dims.iter().map(|&d| d as u64).product::<u64>();
        let buffer = |bytes: u64| bytes.max(MIN_BUFFER_BYTES);
        let blocks = dims
            .iter()
            .map(|&d| d.div_ceil(BLOCK) as u64)
            .product::<u64>();
        let field = texture_bytes(dims, TEXEL);
        let channels = channels as u64;
        let mut medium = channels * (field + buffer(blocks * 4));
        medium += field + texture_bytes([1, 1, 1], TEXEL);
        if opts.fresnel {
            medium += channels * field;
        }
        let fluence = opts.deposit == DepositRule::Fluence;
        let word = buffer(cells * 4);
        let volume = if fluence {
            VOLUME_BUFFERS as u64 * word
        } else {
            PAPER_VOLUME_BUFFERS as u64 * word
                + (VOLUME_BUFFERS - PAPER_VOLUME_BUFFERS) as u64 * MIN_BUFFER_BYTES
        };
        let small = buffer(PARAMS_WORDS as u64 * 4)
            + MAX_LEVELS as u64 * std::mem::size_of::<[u32; 4]>() as u64
            + buffer(STATS_WORDS as u64 * 4)
            + MIN_BUFFER_BYTES;
        let cap = opts.max_patches;
        let lists = 2 * PatchSet::bytes(cap);
        let dep_bytes = if fluence { 0 } else { DEPOSIT_BYTES };
        let scratch: u64 = scratch_bytes(cap, dep_bytes).into_iter().map(buffer).sum();
        let transient = scratch.max(word).max(PatchSet::bytes(0));
        medium + volume + small + lists + scratch + transient
    }

    fn bind(&self, layout: usize, entries: &[wgpu::BindingResource]) -> wgpu::BindGroup {
        let entries: Vec<_> = entries
            .iter()
            .enumerate()
            .map(|(i, r)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: r.clone(),
            })
            .collect();
        self.gpu
            .device
            .create_bind_group(&wgpu::BindGroupDescriptor {
                label: None,
                layout: &self.layouts[layout],
                entries: &entries,
            })
    }

    fn bind_patches(&self, src: &PatchSet, dst: &PatchSet) -> wgpu::BindGroup {
        self.bind(
            1,
            &[
                src.pos.as_entire_binding(),
                src.vel.as_entire_binding(),
                src.aux.as_entire_binding(),
                dst.pos.as_entire_binding(),
                dst.vel.as_entire_binding(),
                dst.aux.as_entire_binding(),
            ],
        )
    }

    /// The Fresnel textures of every index channel (see [`Self::fresnel`]),
    /// computed ([`Interfaces::new`], as the CPU) and uploaded on first use.
    fn fresnel_textures(&self) -> Result<&[Texture], GpuError> {
        if let Some(v) = self.fresnel.get() {
            return Ok(v);
        }
        let medium = self.medium;
        let g = &medium.geometry;
        let faces = Interfaces::new(medium, probe_length(medium));
        let boundary = medium.boundary.as_slice().expect("standard layout");
        let views = self.gpu.checked("uploading the interfaces", || {
            faces
                .sides
                .iter()
                .map(|sides| {
                    let mut rgba = vec![0f32; g.voxel_count() * 4];
                    for ((o, s), &d) in rgba.chunks_exact_mut(4).zip(sides).zip(boundary) {
                        o[..3].copy_from_slice(&[s[0], s[1], d]);
                    }
                    texture(self.gpu, "interfaces", g.dims, &rgba)
                })
                .collect::<Vec<_>>()
        })?;
        Ok(self.fresnel.get_or_init(|| views))
    }

    /// Simulate one light (see [`crate::simulate_light`]): the same
    /// wavefronts, deposit rule and Fresnel transmission as the CPU.
    pub fn simulate(
        &self,
        light: &Light,
        opts: &Options,
        progress: Progress,
    ) -> Result<(LightVolume, Summary), Error> {
        opts.check()?;
        let medium = self.medium;
        let grid = &medium.geometry;
        let gpu = self.gpu;
        let ngroups = medium.channels();
        let cells = grid.voxel_count();
        let fluence = opts.deposit == DepositRule::Fluence;
        let mut summary = Summary::default();
        let crate::Plan {
            mut rules,
            dt,
            max_steps,
        } = crate::Plan::new(light, medium, opts);
        let max_patches = opts.max_patches.min(self.patch_limit());
        let fresnel = if opts.fresnel {
            Some(self.fresnel_textures()?)
        } else {
            None
        };
        // The fluence deposit's counters on the CPU: the chords from a light
        // inside the volume to its start sphere are deposited there, and
        // the GPU's counters are added to them at the end, so the
        // conversion is `Counters::into_volume` itself.
        let mut tally = fluence.then(|| {
            Counters::new(
                grid,
                ngroups,
                [power_bound(light, grid); 3],
                units_per_crossing(crossings_bound(medium, opts.step, max_steps)),
            )
        });
        let (fl_scale, flux_scale) = tally.as_ref().map_or(([0.0; 3], 0.0), Counters::scales);

        // The light volume: one buffer of one word per cell for each array
        // (see `simulate.wgsl`, group 2).
        let vol = |label: &str| gpu.storage_empty(label, cells as u64 * 4);
        let volume: Vec<Buffer> = if fluence {
            let mut v: Vec<_> = ["fluence lo", "fluence hi"]
                .into_iter()
                .flat_map(|w| (0..3).map(move |c| (w, c)))
                .map(|(w, c)| vol(&format!("{w} {c}")))
                .collect();
            v.extend(
                ["flux lo", "flux hi"]
                    .into_iter()
                    .flat_map(|w| (0..3).map(move |c| (w, c)))
                    .map(|(w, c)| vol(&format!("{w} {c}"))),
            );
            v
        } else {
            let mut v: Vec<_> = [
                "deposit keys",
                "deposit stamps",
                "deposit owners",
                "irradiance R",
                "irradiance G",
                "irradiance B",
                "direction x",
                "direction y",
                "direction z",
            ]
            .into_iter()
            .map(vol)
            .collect();
            v.extend(
                (PAPER_VOLUME_BUFFERS..VOLUME_BUFFERS).map(|_| gpu.storage_empty("unused", 0)),
            );
            v
        };
        let volume_group = self.bind(
            2,
            &volume
                .iter()
                .map(|b| b.as_entire_binding())
                .collect::<Vec<_>>(),
        );
        // The level uniforms live as long as their bind groups (so that the
        // tally of live bytes is what the device holds).
        let level_uniforms: Vec<Buffer> = (0..MAX_LEVELS as u32)
            .map(|l| gpu.uniform("pyramid level", &[l, 0, 0, 0]))
            .collect();
        let level_groups: Vec<wgpu::BindGroup> = level_uniforms
            .iter()
            .map(|u| self.bind(3, &[u.as_entire_binding()]))
            .collect();
        let stats = gpu.storage_empty("stats", STATS_WORDS as u64 * 4);
        let params_buf = gpu.uniform("params", &[0u32; PARAMS_WORDS]);
        let top = gpu.storage_empty("pyramid top", 4);

        let mut directions = Vec::with_capacity(ngroups);
        let mut stamp_next = 1u32;
        let (mut p, mut next) = (Patches::default(), Patches::default());
        let mut scratch = refine::Scratch::default();
        for g in 0..ngroups {
            let (mask, group) = crate::group(g, ngroups);
            rules.incident = Incident::new(light, mask);
            // Emission, the start sphere's deposit and the pre-step
            // tessellation are the CPU's own.
            let field = propagate::Bounded::new(medium, g);
            crate::start_wavefront(
                light,
                medium,
                &field,
                opts,
                &rules,
                (mask, group),
                (&mut p, &mut next, &mut scratch),
                tally.as_ref(),
                &mut summary,
            );
            let n0 = p.len();
            if n0 == 0 {
                directions.push(Array4::zeros((grid.dims[0], grid.dims[1], grid.dims[2], 3)));
                continue;
            }
            if n0 > self.patch_limit() {
                return Err(too_large(
                    "the emitted wavefront (patches)",
                    n0 as u64,
                    self.patch_limit() as u64,
                    "raise patch-size or use --backend cpu",
                )
                .into());
            }
            // Fixed point: the largest channel's power at 2^52 units.
            let biggest = p
                .flux
                .iter()
                .fold([0.0f64; 3], |a, f| [0, 1, 2].map(|c| a[c] + f[c]))
                .into_iter()
                .fold(0.0, f64::max)
                .max(1e-300);
            let scale = 2f64.powi((52.0 - biggest.log2().ceil()).clamp(-120.0, 120.0) as i32);

            let mut params = Params([0; PARAMS_WORDS]);
            params.v(0, grid.min);
            params.v(4, grid.spacing());
            params.v(8, 1.0 / grid.spacing());
            params.0[11] = u32::from(opts.integrator != Integrator::Euler);
            for a in 0..3 {
                params.0[12 + a] = grid.dims[a] as u32;
                params.0[20 + a] = (grid.dims[a] as f32 - 1.0).to_bits();
                params.0[24 + a] = grid.dims[a].saturating_sub(2) as u32;
            }
            params.0[15] = group.map_or(-1i32, |c| c as i32) as u32;
            params.v(16, grid.max);
            params.f(19, dt);
            params.0[23] = rules.max_depth as u32;
            params.0[27] = max_patches as u32;
            params.v(28, self.inv_block);
            params.f(31, opts.threshold);
            params.0[32..35].copy_from_slice(&self.empty_dims);
            // The CPU's `span > split_span (1 + 1e-9)` with the tolerance
            // widened to f32's rounding: a patch emitted exactly at the
            // split size must not split on a rounding error.
            params.f(35, rules.split_span * (1.0 + 1e-5));
            params.f(36, scale);
            params.0[38] = u32::from(fluence);
            params.0[39] = u32::from(opts.fresnel);
            params.v(40, DVec3::from_array(fl_scale));
            params.f(43, flux_scale);
            match rules.incident {
                Incident::Uniform(e) => params.f(47, e),
                Incident::Point {
                    position,
                    power,
                    cone,
                } => {
                    params.v(44, position);
                    params.f(47, power);
                    params.0[51] = 1;
                    if let Some((axis, angle, falloff)) = cone {
                        params.v(48, axis);
                        params.0[51] = 2;
                        params.f(52, angle);
                        params.f(53, falloff);
                    }
                }
            }
            params.f(54, rules.dim);
            params.f(55, rules.faint);
            params.f(56, grid.voxel_size());

            // Upload the list.
            // The lists never hold more than `max_patches` (the grants
            // refuse splits beyond it) or the emitted wavefront.
            let most = max_patches.max(n0);
            let cap = (2 * n0).max(FIRST_CAP).min(most);
            let mut sets = [PatchSet::new(gpu, cap), PatchSet::new(gpu, cap)];
            {
                let mut pos = Vec::with_capacity(n0 * 16);
                let mut vel = Vec::with_capacity(n0 * 16);
                let mut aux = Vec::with_capacity(n0 * 12);
                for i in 0..n0 {
                    let x0 = p.corner[0][i].x;
                    for c in 0..4 {
                        let r = &p.corner[c][i];
                        // Corner 0 absolute, the others relative to it.
                        let x = if c == 0 { x0 } else { r.x - x0 };
                        pos.extend([x.x, x.y, x.z, r.opl].map(|v| v as f32));
                        vel.extend([r.v.x, r.v.y, r.v.z, 0.0].map(|v| v as f32));
                    }
                    let (f, f0, e) = (p.flux[i], p.flux0[i], p.irradiance[i]);
                    aux.extend([f[0], f[1], f[2], p.area0[i]].map(|v| v as f32));
                    aux.extend([f0[0], f0[1], f0[2], p.depth[i] as f64].map(|v| v as f32));
                    aux.extend([e[0], e[1], e[2], 0.0].map(|v| v as f32));
                }
                gpu.queue
                    .write_buffer(&sets[0].pos, 0, bytemuck::cast_slice(&pos));
                gpu.queue
                    .write_buffer(&sets[0].vel, 0, bytemuck::cast_slice(&vel));
                gpu.queue
                    .write_buffer(&sets[0].aux, 0, bytemuck::cast_slice(&aux));
            }
            let mut pyr_cap = cap;
            // The paper's deposit keeps each patch's five deposits of a step.
            let dep_bytes = if fluence { 0 } else { DEPOSIT_BYTES };
            let make_pyramid = |n: usize| {
                let [l, s, f, d] = scratch_bytes(n, dep_bytes);
                (
                    gpu.storage_empty("counts pyramid", l),
                    gpu.storage_empty("splits pyramid", s),
                    gpu.storage_empty("fates", f),
                    gpu.storage_empty("deposits", d),
                )
            };
            let (mut levels, mut splits, mut fates, mut deps) = make_pyramid(pyr_cap);
            let (view, empty) = &self.index[g];
            let faces = fresnel.map_or(&self.no_fresnel, |f| &f[g]);
            let bind_medium = |levels: &wgpu::Buffer,
                               splits: &wgpu::Buffer,
                               fates: &wgpu::Buffer,
                               deps: &wgpu::Buffer| {
                self.bind(
                    0,
                    &[
                        params_buf.as_entire_binding(),
                        wgpu::BindingResource::TextureView(&view.view),
                        wgpu::BindingResource::TextureView(&self.extinction.view),
                        empty.as_entire_binding(),
                        stats.as_entire_binding(),
                        levels.as_entire_binding(),
                        splits.as_entire_binding(),
                        fates.as_entire_binding(),
                        deps.as_entire_binding(),
                        wgpu::BindingResource::TextureView(&faces.view),
                    ],
                )
            };
            let mut medium_group = bind_medium(&levels, &splits, &fates, &deps);
            // forward: sets[cur] -> sets[1 - cur].
            let mut cur = 0usize;
            let mut patch_groups = [
                self.bind_patches(&sets[0], &sets[1]),
                self.bind_patches(&sets[1], &sets[0]),
            ];
            {
                let mut enc = gpu.device.create_command_encoder(&Default::default());
                enc.clear_buffer(&stats, 0, None);
                if fluence {
                    // This group's flux vectors (the fluence adds up over
                    // the groups).
                    for b in &volume[6..12] {
                        enc.clear_buffer(b, 0, None);
                    }
                } else {
                    // The keys and the directions (the irradiance of the
                    // other channels stays).
                    enc.clear_buffer(&volume[0], 0, None);
                    for b in &volume[6..9] {
                        enc.clear_buffer(b, 0, None);
                    }
                }
                gpu.queue.submit([enc.finish()]);
            }
            let step_kernel = if fluence { PROPAGATE_TUBE } else { PROPAGATE };

            // The loop: one submission and one read-back (the new list's
            // length) per step.
            let mut n = n0;
            let mut n_old = 0usize;
            let mut step = 0usize;
            let mut expand_first = false;
            loop {
                let stepping = n > 0 && step < max_steps;
                params.set_n(n, n_old);
                params.0[37] = stamp_next;
                stamp_next += 2;
                gpu.queue
                    .write_buffer(&params_buf, 0, bytemuck::cast_slice(&params.0));
                let levels_n = pyramid_levels(n);
                gpu.checked("light simulation step", || {
                    let mut enc = gpu.device.create_command_encoder(&Default::default());
                    enc.clear_buffer(&stats, S_KEPT * 4, Some(8));
                    {
                        let mut pass = enc.begin_compute_pass(&Default::default());
                        pass.set_bind_group(0, &medium_group, &[]);
                        pass.set_bind_group(2, &volume_group, &[]);
                        pass.set_bind_group(3, &level_groups[0], &[]);
                        if expand_first {
                            pass.set_bind_group(1, &patch_groups[1 - cur], &[]);
                            dispatch(&mut pass, &self.kernels[EXPAND], n);
                        }
                        pass.set_bind_group(1, &patch_groups[cur], &[]);
                        if !fluence {
                            for k in DEPOSIT..DEPOSIT + 6 {
                                dispatch(&mut pass, &self.kernels[k], n);
                            }
                        }
                        if stepping {
                            dispatch(&mut pass, &self.kernels[step_kernel], n);
                            dispatch(&mut pass, &self.kernels[ANALYSE], n);
                            for (kernel, base) in [(REDUCE_SPLITS, false), (REDUCE_COUNTS, true)] {
                                if base {
                                    pass.set_bind_group(3, &level_groups[0], &[]);
                                    dispatch(&mut pass, &self.kernels[GRANT], n);
                                }
                                for (l, &(_, len)) in levels_n.iter().enumerate().skip(1) {
                                    pass.set_bind_group(3, &level_groups[l], &[]);
                                    dispatch(&mut pass, &self.kernels[kernel], len);
                                }
                            }
                        } else {
                            dispatch(&mut pass, &self.kernels[CULL_REST], n);
                        }
                    }
                    if stepping {
                        let (off, _) = *levels_n.last().expect("a level");
                        enc.copy_buffer_to_buffer(&levels, off as u64 * 4, &top, 0, 4);
                    }
                    gpu.queue.submit([enc.finish()]);
                })?;
                if !stepping {
                    summary.step_limit += n;
                    break;
                }
                step += 1;
                let total = gpu.read::<u32>(&top, 1)?[0] as usize;
                summary.peak_patches = summary.peak_patches.max(total);
                progress(step, total);
                // The walk writes `total` patches into the other list.
                let dst = 1 - cur;
                if total > sets[dst].cap {
                    let cap = total.max(2 * sets[dst].cap).min(most);
                    if total > cap {
                        return Err(too_large(
                            "the wavefront (patches)",
                            total as u64,
                            cap as u64,
                            "lower max-patches",
                        )
                        .into());
                    }
                    // The walk overwrites the other list: free it, with the
                    // bind groups that hold it, before making the larger.
                    drop(patch_groups);
                    sets[dst] = PatchSet::new(gpu, 0);
                    sets[dst] = PatchSet::new(gpu, cap);
                    patch_groups = [
                        self.bind_patches(&sets[0], &sets[1]),
                        self.bind_patches(&sets[1], &sets[0]),
                    ];
                }
                if total > pyr_cap {
                    // The walk still reads the old pyramid: carry it over.
                    let new_cap = total.max(2 * pyr_cap).min(most);
                    let (l2, s2, f2, d2) = make_pyramid(new_cap);
                    let mut enc = gpu.device.create_command_encoder(&Default::default());
                    enc.copy_buffer_to_buffer(&levels, 0, &l2, 0, levels.size());
                    gpu.queue.submit([enc.finish()]);
                    (levels, splits, fates, deps) = (l2, s2, f2, d2);
                    pyr_cap = new_cap;
                    medium_group = bind_medium(&levels, &splits, &fates, &deps);
                }
                n_old = n;
                n = total;
                expand_first = true;
                cur = dst;
                if n == 0 {
                    break;
                }
            }
            summary.steps = summary.steps.max(step);

            // Tallies.
            let s = gpu.read::<u32>(&stats, STATS_WORDS)?;
            let energy = |cat: usize, c: usize| {
                let w = 2 * (3 * cat + c);
                (s[w] as f64 + s[w + 1] as f64 * 4294967296.0) / scale
            };
            for c in 0..3 {
                summary.absorbed_power[c] += energy(0, c);
                summary.exited_power[c] += energy(1, c);
                summary.culled_power[c] += energy(2, c);
                summary.reflected_power[c] += energy(3, c);
                summary.trapped_power[c] += energy(4, c);
            }
            summary.exited += s[S_EXITED] as usize;
            summary.absorbed += s[S_ABSORBED] as usize;
            summary.faint += s[S_FAINT] as usize;
            summary.caustic += s[S_CAUSTIC] as usize;
            summary.held += s[S_HELD] as usize;
            match tally.as_mut() {
                Some(t) => {
                    for a in 0..3 {
                        let units = read_u64(gpu, &volume[6 + a], &volume[9 + a], cells)?;
                        let units: Vec<i64> = units.into_iter().map(|u| u as i64).collect();
                        t.add_flux_units(g, a, &units);
                    }
                }
                None => directions.push(read_rgb(gpu, &volume[6..9], grid.dims)?),
            }
        }
        let volume = match tally {
            Some(mut t) => {
                for c in 0..3 {
                    let units = read_u64(gpu, &volume[c], &volume[3 + c], cells)?;
                    t.add_fluence_units(c, &units);
                }
                t.into_volume()
            }
            None => {
                let irradiance = read_rgb(gpu, &volume[3..6], grid.dims)?;
                LightVolume::from_rays(irradiance, directions)
            }
        };
        crate::check_finite(&volume, &summary)?;
        Ok((volume, summary))
    }
}

/// A 64-bit counter per cell from its low and high words.
fn read_u64(
    gpu: &Gpu,
    lo: &wgpu::Buffer,
    hi: &wgpu::Buffer,
    cells: usize,
) -> Result<Vec<u64>, GpuError> {
    let (lo, hi) = (gpu.read::<u32>(lo, cells)?, gpu.read::<u32>(hi, cells)?);
    Ok(lo
        .into_iter()
        .zip(hi)
        .map(|(l, h)| l as u64 | (h as u64) << 32)
        .collect())
}

/// Three per-component buffers interleaved into `(nx, ny, nz, 3)`.
fn read_rgb(gpu: &Gpu, bufs: &[Buffer], dims: [usize; 3]) -> Result<Array4<f32>, GpuError> {
    let cells = dims[0] * dims[1] * dims[2];
    let mut out = Array4::zeros((dims[0], dims[1], dims[2], 3));
    let flat = out.as_slice_mut().expect("contiguous");
    for (c, b) in bufs.iter().enumerate() {
        let v = gpu.read::<f32>(b, cells)?;
        for (o, x) in flat.chunks_exact_mut(3).zip(v) {
            o[c] = x;
        }
    }
    Ok(out)
}
