//! The `gpu` backend of the view renderer: the CPU renderer's image
//! formation ([`crate::render`], [Ihrke07 sec 5.3], [Ihrke07 eqs 1-12]) as a
//! wgpu compute shader (`render.wgsl`), in f32.
//!
//! * The medium, its packed properties ([`Properties`], with the same
//!   probe for the interface sides), and the light volumes are 3D textures
//!   (`rgba32float`/`rg32float`), read with `textureLoad` and a manual
//!   trilinear reconstruction in the grid's cell-centre convention (32-bit
//!   float filtering is optional in WebGPU). Textures avoid the storage
//!   binding limit (128 MiB on lavapipe): a 256^3 grid fits the 3D texture
//!   limit of 256.
//! * Empty-space skipping uses the CPU's [`MacroCells`] (block table and
//!   per-voxel clear distance), uploaded as one storage buffer.
//! * Eye rays: the camera's sample directions ([`Camera::ray`], the same
//!   stratified, hashed positions as the CPU) are computed on the host in
//!   f64 and uploaded as f32.
//! * The device's limit of 16 sampled textures per stage leaves room for one
//!   light volume at a time: a frame is one pass per light volume (at least
//!   one), each marching the same rays; pass 0 adds what needs no light
//!   volume, every pass its volume's in-scatter and receiver light (the
//!   image is linear in them).
//! * Tone mapping stays on the host ([`eikon_optics::image`]).
//! * Sharp interfaces ([`GpuRenderer::with_scene`]): the scene's regions
//!   as a storage buffer (`eikon_grid::region::gpu_regions`, objects in
//!   precedence order, then the ambient medium) and `sharp.wgsl`, the
//!   CPU's `march_sharp` over the shared `surface` and `region` modules
//!   (every shape and index profile, VDB grids included; the data of
//!   solids of revolution, meshes and grids in a second buffer). A
//!   curved step is cut at a surface by bisection on its length
//!   (the CPU: false position), and a crossing's tolerance is 4e-6 of the
//!   scene's scale (the CPU: 1e-9 voxels, below f32's resolution).
//!   Measured against the CPU on lavapipe (`tests/gpu_sharp.rs`): PSNR
//!   99.5 dB (glass sphere), 137 dB (Luneburg lens), 92 dB (rotated box,
//!   cylinder, scattering slab, half-space), 47.9 dB (dispersive cylinder),
//!   57.4 dB (rounded box, torus, superquadric star), 111.1 dB (wine
//!   glass), 59.1 dB (VDB drop), 87.7 dB (two meshes). A kernel holds only
//!   its scene's shapes' code (`region::only_kinds`): drivers inline every
//!   call, and every shape at every call site took minutes to compile.
//!   For the same reason a kernel holds one march (`sharp.wgsl` or
//!   `march.wgsl`, the other a stand-in), called from one place (the
//!   colour channels in a loop).
//!
//! Differences from the CPU: f32 instead of f64 arithmetic (the plane-hit
//! rounding allowance is 2e-6 instead of 1e-9 of the scene's scale), and
//! the samples of a pixel and the passes are summed in a different order.
//! A zero direction looks up black instead of NaN in a lat-long map. The
//! nudge past a uniform block's face is at least 1e-6 of the position
//! (1e-6 voxels alone is below f32 resolution and would leave the ray on
//! the face), and the ray is then put at least 2e-6 of the scene's scale
//! past the face along its axis: `x + d t` rounds to either side of the
//! face in f32, and a ray left on it crossed the same block again with a
//! step of nothing (one to eight times per ray, its path parting from the
//! CPU's). Measured against the CPU on lavapipe (`tests/gpu.rs`): PSNR
//! 47.6 to 140 dB over the test scenes, 82.7 dB on the 800x600 glass
//! sphere (45.6 dB before that fix); ray steps and empty-space skips
//! ([`GpuRenderer::render_with_stats`]) within 0.4% of the CPU's.

use crate::background::{Checker, Surroundings};
use crate::macrocell::MacroCells;
use crate::properties::Properties;
use crate::render::{probe_length, Options, Stats, MIRROR_COS};
use eikon_gpu::{texture_bytes, Buffer, Gpu, GpuError, Texture, MIN_BUFFER_BYTES};
use eikon_grid::blocks::BLOCK;
use eikon_grid::geometry::GridGpu;
use eikon_grid::region::{gpu_regions, RegionGpu};
use eikon_grid::{GridGeometry, Integrator, Interfaces, Light, Medium, Scene};
use eikon_optics::{Camera, Environment, Image};
use eikon_shader::{compose, layout, Consts, Layout, VECTOR};
use eikon_wavefront::LightVolume;
use glam::DVec3;
use std::time::Instant;

const SHADER: &str = include_str!("render.wgsl");
/// The march with sharp interfaces, and its stand-ins for other scenes.
const SHARP: &str = include_str!("sharp.wgsl");
const SHARP_STUB: &str = include_str!("sharp_stub.wgsl");
/// The march through the voxel grid, and its stand-in for scenes with
/// sharp interfaces.
const MARCH: &str = include_str!("march.wgsl");
const MARCH_STUB: &str = include_str!("march_stub.wgsl");

/// Lights the shader's uniform block holds (for the receiver's direct
/// lighting outside the grid).
pub const MAX_LIGHTS: usize = 16;

/// Largest eye-ray buffer of one chunk of samples, bytes.
const RAY_CHUNK: u64 = 64 << 20;

/// Workgroup edge (8 x 8 pixels).
const TILE: u32 = 8;

/// Bytes per pixel of the radiance sums and of one sample's eye-ray
/// directions (three f32 each).
const PIXEL_BYTES: u64 = 12;

/// Bytes of the frame's counters: ray-equation steps and empty-space
/// skips, 64 bits each.
const COUNTER_BYTES: u64 = 16;

/// The rounding allowance of a plane hit relative to the scene's scale
/// (`background.rs`: 1e-9 in f64; f32's rounding needs more).
const PLANE_EPS: f32 = 2e-6;

/// Kinds of [`ViewLight`].
const LIGHT_DIRECTIONAL: u32 = 0;
const LIGHT_POINT: u32 = 1;
const LIGHT_SPOT: u32 = 2;

/// Format of the medium's and the light volumes' textures, and of the
/// interface sides.
const RGBA: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;
const RG: wgpu::TextureFormat = wgpu::TextureFormat::Rg32Float;

layout! {
    /// A light of the receiver's direct lighting outside the grid
    /// (`background.rs` `direct`).
    pub struct ViewLight {
        /// A point or spot light's position.
        pub position: [f32; 3],
        /// `LIGHT_DIRECTIONAL`, `LIGHT_POINT` or `LIGHT_SPOT`.
        pub kind: u32,
        /// A directional light's direction of travel, a spot light's
        /// unit axis.
        pub direction: [f32; 3],
        /// The spot's half-angle, degrees.
        pub angle: f32,
        /// RGB power (a directional light's irradiance).
        pub power: [f32; 3],
        /// The spot's falloff band, degrees.
        pub falloff: f32,
    }
}

layout! {
    /// The uniform block of the view renderer (`P` in `render.wgsl`).
    pub struct ViewParams {
        /// The grid.
        pub grid: GridGpu,
        /// Index channels (3 with dispersion, else 1).
        pub channels: u32,
        /// Image width, pixels.
        pub width: u32,
        /// Image height, pixels.
        pub height: u32,
        /// Most ray-equation steps per eye ray.
        pub budget: u32,
        /// Lights in `lights`.
        pub light_count: u32,
        /// `INTEGRATOR_EULER` or `INTEGRATOR_RK4`.
        pub integrator: u32,
        /// 1: skip empty space.
        pub skip_empty: u32,
        /// 1: something emits.
        pub emits: u32,
        /// 1: something scatters.
        pub scatters: u32,
        /// 0: a constant environment, 1: a lat-long map.
        pub env_kind: u32,
        /// The map's width, texels.
        pub env_width: u32,
        /// Its height.
        pub env_height: u32,
        /// 1: a checkerboard.
        pub has_checker: u32,
        /// 1: a receiver plane.
        pub has_receiver: u32,
        /// Words of one channel's block table.
        pub skip_words: u32,
        /// Where the clear distances start.
        pub clear_base: u32,
        /// Macro-cells per axis.
        pub block_dims: [u32; 3],
        /// Words of one channel's clear distances.
        pub clear_words: u32,
        /// `1 / (spacing BLOCK)` per axis.
        pub inv_block: [f32; 3],
        /// Rays stop below this transmittance.
        pub min_transmittance: f32,
        /// The eye.
        pub eye: [f32; 3],
        /// The eye-ray step, world units.
        pub step: f32,
        /// A constant environment's radiance.
        pub env_const: [f32; 3],
        /// Padding.
        pub pad0: f32,
        /// A point on the checkerboard.
        pub checker_point: [f32; 3],
        /// Its squares' edge.
        pub checker_square: f32,
        /// Its unit normal.
        pub checker_normal: [f32; 3],
        /// Padding.
        pub pad1: f32,
        /// Its first in-plane axis.
        pub checker_u: [f32; 3],
        /// Padding.
        pub pad2: f32,
        /// Its second in-plane axis.
        pub checker_w: [f32; 3],
        /// Padding.
        pub pad3: f32,
        /// The colours of its squares.
        pub checker_color0: [f32; 3],
        /// Padding.
        pub pad4: f32,
        /// The other colour.
        pub checker_color1: [f32; 3],
        /// Padding.
        pub pad5: f32,
        /// A point on the receiver.
        pub receiver_point: [f32; 3],
        /// Padding.
        pub pad6: f32,
        /// Its unit normal.
        pub receiver_normal: [f32; 3],
        /// Padding.
        pub pad7: f32,
        /// Its RGB albedo.
        pub receiver_albedo: [f32; 3],
        /// Padding.
        pub pad8: f32,
        /// The lights, `light_count` of them.
        pub lights: [ViewLight; MAX_LIGHTS],
        /// 1: sharp interfaces (`march_sharp` over `regions`).
        pub sharp: u32,
        /// Objects in the region table (the ambient medium follows them).
        pub region_count: u32,
        /// With sharp interfaces: the length below which two points on a
        /// ray are one (a crossing is found only beyond it, the far side of
        /// a surface is probed this far from it), world units.
        pub sharp_eps: f32,
        /// Padding.
        pub pad9: u32,
    }
}

layout! {
    /// The uniform of one pass (`PASS` in `render.wgsl`).
    pub struct RenderPass {
        /// 1: the pass adds what needs no light volume.
        pub base: u32,
        /// 1: a light volume is bound.
        pub lit: u32,
        /// Flux arrays of the volume (1, or 3 with dispersion).
        pub flux_arrays: u32,
        /// Samples in the chunk.
        pub samples: u32,
    }
}

fn declarations() -> String {
    let c = Consts::new()
        .u32("TILE", TILE)
        .u32("MAX_LIGHTS", MAX_LIGHTS as u32)
        .u32("LIGHT_DIRECTIONAL", LIGHT_DIRECTIONAL)
        .u32("LIGHT_POINT", LIGHT_POINT)
        .u32("LIGHT_SPOT", LIGHT_SPOT)
        .f32("MIRROR_COS", MIRROR_COS as f32)
        .f32("PLANE_EPS", PLANE_EPS)
        .u32("NONE", u32::MAX)
        .f32("INF", 1e30);
    format!(
        "{}{}{}{}",
        ViewLight::declaration(),
        ViewParams::declaration(),
        RenderPass::declaration(),
        c.wgsl()
    )
}

/// The renderer's full WGSL: its generated declarations, the shared
/// modules and `render.wgsl`; with `sharp` interfaces the `region` modules
/// and `sharp.wgsl`, else `march.wgsl` (the grid's march), each kernel
/// with stand-ins for the other's march: drivers inline every call, and a
/// kernel that does not carry the march it never runs compiles several
/// times faster on lavapipe.
pub fn source(sharp: bool) -> String {
    let mut modules: Vec<&'static eikon_shader::Module> = vec![
        &VECTOR,
        &eikon_grid::geometry::WGSL,
        &eikon_grid::ray::WGSL,
        &eikon_optics::fresnel::WGSL,
        &eikon_optics::phase::WGSL,
        &eikon_optics::spot::WGSL,
    ];
    if sharp {
        modules.push(&eikon_grid::region::WGSL);
        modules.push(&eikon_grid::region::STEP_WGSL);
    }
    let main = if sharp {
        format!("{SHADER}\n{SHARP}\n{MARCH_STUB}")
    } else {
        format!("{SHADER}\n{SHARP_STUB}\n{MARCH}")
    };
    compose(&declarations(), &modules, &main)
}

/// What the GPU renderer's device memory depends on, all known before a
/// run (see [`GpuRenderer::device_bytes`]), so that a render that does not
/// fit the device can be refused before it starts.
#[derive(Clone, Copy, Debug, Default)]
pub struct DeviceSize {
    /// Grid cells along x, y and z.
    pub dims: [usize; 3],
    /// Index channels of the medium: 3 with dispersion, else 1.
    pub channels: usize,
    /// Light volumes rendered (one per light; 0 renders without).
    pub volumes: usize,
    /// Flux arrays of each light volume: 3 with dispersion, else 1.
    pub flux_arrays: usize,
    /// Whether the medium emits (true when unsure: an upper bound).
    pub emission: bool,
    /// Whether empty-space skipping is on ([`Options::skip_empty`]).
    pub skip_empty: bool,
    /// Texels of a lat-long environment map (0 for a constant one).
    pub environment_texels: usize,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Samples per pixel.
    pub samples: u32,
    /// Objects of the region table with sharp interfaces (0 without:
    /// the table is then one placeholder region).
    pub regions: usize,
    /// Records (16 bytes) of the regions' shape data (profiles, mesh
    /// triangles and BVH nodes; at least one).
    pub region_data: usize,
}

impl DeviceSize {
    /// The size of a render of `medium` lit by `volumes` under `env`
    /// through `camera` with `opts` (without sharp interfaces: set
    /// [`DeviceSize::regions`] for a sharp scene).
    pub fn of(
        medium: &Medium,
        volumes: &[LightVolume],
        env: &Environment,
        camera: &Camera,
        opts: &Options,
    ) -> Self {
        DeviceSize {
            dims: medium.geometry.dims,
            channels: medium.channels(),
            volumes: volumes.len(),
            flux_arrays: volumes.first().map_or(1, |v| v.flux.len()),
            emission: medium.emission.iter().any(|&e| e != 0.0),
            skip_empty: opts.skip_empty,
            environment_texels: env.texels(),
            width: camera.width(),
            height: camera.height(),
            samples: camera.samples(),
            regions: 0,
            region_data: 1,
        }
    }
}

/// The view renderer on a GPU, with the scene uploaded.
pub struct GpuRenderer<'a> {
    gpu: &'a Gpu,
    camera: Camera,
    seed: u64,
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    params: Buffer,
    /// idx0..2, propa, propb, emission, sides0..2.
    medium_views: Vec<wgpu::TextureView>,
    /// Per pass: fluence, flux vector 0..2.
    volume_views: Vec<[wgpu::TextureView; 4]>,
    /// Per pass: how many flux arrays its volume has (1, or 3 with
    /// dispersion).
    volume_arrays: Vec<u32>,
    skip: Buffer,
    env: Buffer,
    rays: Buffer,
    accum: Buffer,
    /// The frame's ray-equation steps and empty-space skips, each a
    /// 64-bit count in two words (low first), summed by the shader.
    counters: Buffer,
    /// Samples per chunk of rays.
    chunk: u32,
    /// The rays of the only chunk are uploaded once.
    single_chunk: bool,
    /// Whether there are light volumes (without, one pass binds a dark
    /// placeholder).
    lit: bool,
    /// With sharp interfaces the regions (`region.rs` `gpu_regions`), else
    /// one placeholder.
    regions: Buffer,
    /// Their shapes' data, else one placeholder record.
    region_data: Buffer,
    _textures: Vec<Texture>,
}

fn f3(v: DVec3) -> [f32; 3] {
    v.to_array().map(|x| x as f32)
}

fn too_big(gpu: &Gpu, message: String) -> GpuError {
    GpuError::Device {
        adapter: gpu.info.name.clone(),
        message,
    }
}

/// A texture of 3-vectors per cell (`(nx, ny, nz, 3)` C order) as RGBA.
fn vec3_texture(gpu: &Gpu, label: &str, dims: [usize; 3], data: &[f32]) -> Texture {
    let [_, ny, nz] = dims;
    gpu.texture_3d(label, dims, RGBA, &|i0, i1| {
        let mut out = Vec::with_capacity((i1 - i0) * ny * nz * 4);
        for c in data[i0 * ny * nz * 3..i1 * ny * nz * 3].chunks_exact(3) {
            out.extend_from_slice(&[c[0], c[1], c[2], 0.0]);
        }
        bytemuck::cast_slice(&out).to_vec()
    })
}

/// A texture of `width` floats per cell straight from a C-order array.
fn flat_texture(
    gpu: &Gpu,
    label: &str,
    dims: [usize; 3],
    format: wgpu::TextureFormat,
    width: usize,
    data: &[f32],
) -> Texture {
    let [_, ny, nz] = dims;
    let layer = ny * nz * width;
    gpu.texture_3d(label, dims, format, &|i0, i1| {
        bytemuck::cast_slice(&data[i0 * layer..i1 * layer]).to_vec()
    })
}

/// `bytes` against the device's storage binding limit.
fn check_binding(gpu: &Gpu, what: &str, bytes: u64) -> Result<(), GpuError> {
    let max = u64::from(gpu.device.limits().max_storage_buffer_binding_size);
    if bytes > max {
        return Err(too_big(
            gpu,
            format!("the {what} needs {bytes} bytes, over the storage binding limit of {max}"),
        ));
    }
    Ok(())
}

/// The index channels (absent channels bound to the first), the packed
/// properties ([`Properties`]), the emission and the interface sides as
/// textures.
fn upload_medium(gpu: &Gpu, medium: &Medium, properties: &Properties) -> MediumTextures {
    let dims = medium.geometry.dims;
    let [_, ny, nz] = dims;
    let channels = medium.channels();
    let mut textures = Vec::new();
    for (c, idx) in medium.index.iter().enumerate() {
        let data = idx.as_slice().expect("standard layout");
        textures.push(flat_texture(
            gpu,
            &format!("index {c}"),
            dims,
            RGBA,
            4,
            data,
        ));
    }
    let scatters = properties
        .texels
        .iter()
        .any(|t| t[1].truncate().max_element() > 0.0);
    let props: Vec<[f32; 4]> = properties
        .texels
        .iter()
        .flat_map(|t| [t[0].to_array(), t[1].to_array()])
        .collect();
    let flat: &[f32] = bytemuck::cast_slice(&props);
    let layer = ny * nz;
    let pick = |half: usize| {
        move |i0: usize, i1: usize| -> Vec<u8> {
            let mut out = Vec::with_capacity((i1 - i0) * layer * 16);
            for f in i0 * layer..i1 * layer {
                out.extend_from_slice(bytemuck::cast_slice(
                    &flat[8 * f + 4 * half..8 * f + 4 * half + 4],
                ));
            }
            out
        }
    };
    let propa = gpu.texture_3d("sigma delta", dims, RGBA, &pick(0));
    let propb = gpu.texture_3d("scatter g", dims, RGBA, &pick(1));
    let emission = match &properties.emission {
        Some(e) => {
            let data: Vec<f32> = e.iter().flat_map(|v| v.to_array()).collect();
            flat_texture(gpu, "emission", dims, RGBA, 4, &data)
        }
        None => flat_texture(gpu, "no emission", [1, 1, 1], RGBA, 4, &[0.0; 4]),
    };
    let sides: Vec<Texture> = properties
        .sides
        .sides
        .iter()
        .enumerate()
        .map(|(c, s)| {
            let data: &[f32] = bytemuck::cast_slice(s);
            flat_texture(gpu, &format!("sides {c}"), dims, RG, 2, data)
        })
        .collect();
    let view = |t: &wgpu::Texture| t.create_view(&Default::default());
    let mut views: Vec<wgpu::TextureView> = (0..3)
        .map(|c| view(&textures[c.min(channels - 1)]))
        .collect();
    views.push(view(&propa));
    views.push(view(&propb));
    views.push(view(&emission));
    views.extend((0..3).map(|c| view(&sides[c.min(channels - 1)])));
    textures.extend([propa, propb, emission]);
    textures.extend(sides);
    MediumTextures {
        views,
        emits: properties.emission.is_some(),
        scatters,
        textures,
    }
}

/// One pass per light volume: its fluence and flux arrays as textures; a
/// dark placeholder without any.
fn upload_volumes(gpu: &Gpu, dims: [usize; 3], volumes: &[LightVolume]) -> VolumeTextures {
    let view = |t: &wgpu::Texture| t.create_view(&Default::default());
    let mut out = VolumeTextures {
        views: Vec::new(),
        arrays: Vec::new(),
        textures: Vec::new(),
    };
    for (j, v) in volumes.iter().enumerate() {
        let irr = vec3_texture(
            gpu,
            &format!("fluence {j}"),
            dims,
            v.fluence.as_slice().expect("standard layout"),
        );
        out.arrays.push(v.flux.len() as u32);
        let dirs: Vec<Texture> = v
            .flux
            .iter()
            .enumerate()
            .map(|(c, d)| {
                vec3_texture(
                    gpu,
                    &format!("flux {j}.{c}"),
                    dims,
                    d.as_slice().expect("standard layout"),
                )
            })
            .collect();
        let k = dirs.len();
        out.views.push([
            view(&irr),
            view(&dirs[0]),
            view(&dirs[1.min(k - 1)]),
            view(&dirs[2.min(k - 1)]),
        ]);
        out.textures.push(irr);
        out.textures.extend(dirs);
    }
    if volumes.is_empty() {
        let dark = flat_texture(gpu, "no light volume", [1, 1, 1], RGBA, 4, &[0.0; 4]);
        out.views
            .push([view(&dark), view(&dark), view(&dark), view(&dark)]);
        out.arrays.push(1);
        out.textures.push(dark);
    }
    out
}

/// The empty-space tables of every channel ([`MacroCells`]), or one word
/// without skipping.
fn skip_table(medium: &Medium, skip_empty: bool) -> SkipTable {
    let g = &medium.geometry;
    let blocks = g.dims.map(|d| d.div_ceil(BLOCK));
    let nblocks = blocks[0] * blocks[1] * blocks[2];
    let clear_words = g.voxel_count().div_ceil(4);
    let mut words: Vec<u32> = Vec::new();
    if skip_empty {
        let cells: Vec<MacroCells> = (0..medium.channels())
            .map(|c| MacroCells::new(medium, c))
            .collect();
        for m in &cells {
            debug_assert_eq!(m.blocks.dims, blocks);
            for c in &m.cells {
                if c[0].is_nan() {
                    words.extend([u32::MAX; 4]);
                } else {
                    words.extend(c.map(f32::to_bits));
                }
            }
        }
        for m in &cells {
            let mut w = vec![0u32; clear_words];
            for (f, &d) in m.clear.iter().enumerate() {
                w[f / 4] |= u32::from(d) << (8 * (f % 4));
            }
            words.extend(w);
        }
    } else {
        words.push(0);
    }
    SkipTable {
        words,
        blocks,
        block_words: 4 * nblocks,
        clear_words,
    }
}

/// The environment: a constant, or a lat-long map's RGB texels.
fn environment_data(surroundings: &Surroundings) -> EnvironmentData {
    match &surroundings.environment {
        Environment::Constant(c) => EnvironmentData {
            kind: 0,
            width: 1,
            height: 1,
            constant: *c,
            texels: vec![0.0; 3],
        },
        Environment::LatLong(m) => EnvironmentData {
            kind: 1,
            width: m.width() as u32,
            height: m.height() as u32,
            constant: [0.0; 3],
            texels: m.data().iter().flatten().copied().collect(),
        },
    }
}

/// The eye rays of one chunk of samples (at most [`RAY_CHUNK`] bytes, at
/// least one sample), the radiance sums and the counters, checked against
/// the device's limits.
fn frame_buffers(gpu: &Gpu, camera: &Camera) -> Result<FrameBuffers, GpuError> {
    let limits = gpu.device.limits();
    let (w, h) = (camera.width(), camera.height());
    let pixels = u64::from(w) * u64::from(h);
    check_binding(gpu, "image", pixels * PIXEL_BYTES)?;
    let groups = w.div_ceil(TILE).max(h.div_ceil(TILE));
    if groups > limits.max_compute_workgroups_per_dimension {
        return Err(too_big(
            gpu,
            format!(
                "the {w}x{h} image needs {groups} workgroups along one axis, over the limit of {}",
                limits.max_compute_workgroups_per_dimension
            ),
        ));
    }
    let per_sample = pixels * PIXEL_BYTES;
    check_binding(gpu, "eye rays of one sample", per_sample)?;
    let max_binding = u64::from(limits.max_storage_buffer_binding_size);
    let chunk = (RAY_CHUNK.min(max_binding) / per_sample).clamp(1, u64::from(camera.samples()));
    Ok(FrameBuffers {
        rays: gpu.storage_empty("eye rays", per_sample * chunk),
        accum: gpu.storage_empty("radiance", pixels * PIXEL_BYTES),
        counters: gpu.storage_empty("render counters", COUNTER_BYTES),
        chunk: chunk as u32,
    })
}

/// With sharp interfaces on the GPU, the length below which two points on
/// a ray are one ([`ViewParams::sharp_eps`]): the CPU's is a billionth of a
/// voxel, below f32's resolution; here a few hundred ulps of the scene's
/// scale, well above the rounding of a crossing point (a few ulps) so that
/// a segment starting on a surface does not find its own start, and the
/// far side is probed beyond that rounding.
fn sharp_eps(g: &GridGeometry) -> f64 {
    let scale = g.min.abs().max(g.max.abs()).max_element() + g.voxel_size();
    4e-6 * scale
}

/// The uniform block of a render.
fn view_params(
    medium: &Medium,
    surroundings: &Surroundings,
    camera: &Camera,
    opts: &Options,
    (textures, table, env): (&MediumTextures, &SkipTable, &EnvironmentData),
) -> ViewParams {
    let g = &medium.geometry;
    let ds = opts.step * g.voxel_size();
    let budget = (64.0 * g.diagonal() / ds) as u64 + 16;
    let channels = medium.channels();
    let checker = surroundings.checker.unwrap_or(Checker {
        point: DVec3::ZERO,
        normal: DVec3::ZERO,
        u: DVec3::ZERO,
        w: DVec3::ZERO,
        square: 1.0,
        colors: [DVec3::ZERO; 2],
    });
    let receiver = surroundings.receiver.as_ref();
    let mut lights = [ViewLight::default(); MAX_LIGHTS];
    for (out, l) in lights.iter_mut().zip(surroundings.lights) {
        *out = match l {
            Light::Directional { direction, power } => ViewLight {
                kind: LIGHT_DIRECTIONAL,
                direction: f3(*direction),
                power: f3(*power),
                ..Default::default()
            },
            Light::Point { position, power } => ViewLight {
                kind: LIGHT_POINT,
                position: f3(*position),
                power: f3(*power),
                ..Default::default()
            },
            Light::Spot {
                position,
                direction,
                angle,
                falloff,
                power,
            } => ViewLight {
                kind: LIGHT_SPOT,
                position: f3(*position),
                direction: f3(*direction),
                angle: *angle as f32,
                power: f3(*power),
                falloff: *falloff as f32,
            },
        };
    }
    ViewParams {
        grid: GridGpu::new(g),
        channels: channels as u32,
        width: camera.width(),
        height: camera.height(),
        budget: budget.min(u64::from(u32::MAX)) as u32,
        light_count: surroundings.lights.len() as u32,
        integrator: if opts.integrator == Integrator::Euler {
            Integrator::Euler as u32
        } else {
            Integrator::Rk4 as u32
        },
        skip_empty: u32::from(opts.skip_empty),
        emits: u32::from(textures.emits),
        scatters: u32::from(textures.scatters),
        env_kind: env.kind,
        env_width: env.width,
        env_height: env.height,
        has_checker: u32::from(surroundings.checker.is_some()),
        has_receiver: u32::from(receiver.is_some()),
        skip_words: table.block_words as u32,
        clear_base: (channels * table.block_words) as u32,
        clear_words: table.clear_words as u32,
        block_dims: table.blocks.map(|b| b as u32),
        inv_block: f3(1.0 / (g.spacing() * BLOCK as f64)),
        min_transmittance: opts.min_transmittance as f32,
        eye: f3(camera.position()),
        step: ds as f32,
        env_const: env.constant,
        checker_point: f3(checker.point),
        checker_square: checker.square as f32,
        checker_normal: f3(checker.normal),
        checker_u: f3(checker.u),
        checker_w: f3(checker.w),
        checker_color0: f3(checker.colors[0]),
        checker_color1: f3(checker.colors[1]),
        receiver_point: f3(receiver.map_or(DVec3::ZERO, |r| r.point)),
        receiver_normal: f3(receiver.map_or(DVec3::ZERO, |r| r.normal)),
        receiver_albedo: f3(receiver.map_or(DVec3::ZERO, |r| r.albedo)),
        lights,
        ..Default::default()
    }
}

/// The kernel of [`source`] and its bind group layout.
fn compile(
    gpu: &Gpu,
    kinds: Option<u32>,
) -> Result<(wgpu::ComputePipeline, wgpu::BindGroupLayout), GpuError> {
    gpu.checked("view renderer pipeline", || {
        let tex = |binding: u32| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Float { filterable: false },
                view_dimension: wgpu::TextureViewDimension::D3,
                multisampled: false,
            },
            count: None,
        };
        let buf = |binding: u32, ty: wgpu::BufferBindingType| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty,
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let mut entries = vec![
            buf(0, wgpu::BufferBindingType::Uniform),
            buf(1, wgpu::BufferBindingType::Uniform),
        ];
        entries.extend((2..15).map(tex));
        for b in (15..18).chain([20, 21]) {
            entries.push(buf(b, wgpu::BufferBindingType::Storage { read_only: true }));
        }
        for b in 18..20 {
            entries.push(buf(
                b,
                wgpu::BufferBindingType::Storage { read_only: false },
            ));
        }
        let layout = gpu
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("view renderer"),
                entries: &entries,
            });
        let pl = gpu
            .device
            .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("view renderer"),
                bind_group_layouts: &[&layout],
                push_constant_ranges: &[],
            });
        let module = gpu
            .device
            .create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some("view renderer"),
                source: wgpu::ShaderSource::Wgsl(
                    match kinds {
                        // Only the scene's shapes' code (`only_kinds`).
                        Some(k) => eikon_grid::region::only_kinds(&source(true), k),
                        None => source(false),
                    }
                    .into(),
                ),
            });
        let pipeline = gpu
            .device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some("view renderer"),
                layout: Some(&pl),
                module: &module,
                entry_point: Some("render"),
                compilation_options: Default::default(),
                cache: None,
            });
        (pipeline, layout)
    })
}

/// The medium's textures as the kernel binds them.
struct MediumTextures {
    /// idx0..2, propa, propb, emission, sides0..2.
    views: Vec<wgpu::TextureView>,
    /// Whether anything emits, and anything scatters.
    emits: bool,
    scatters: bool,
    textures: Vec<Texture>,
}

/// The light volumes as the kernel binds them, one pass each.
struct VolumeTextures {
    /// Per pass: fluence, flux vector 0..2.
    views: Vec<[wgpu::TextureView; 4]>,
    /// Per pass: its flux arrays (1, or 3 with dispersion).
    arrays: Vec<u32>,
    textures: Vec<Texture>,
}

/// The frame's buffers: eye rays of one chunk of samples, radiance sums,
/// counters.
struct FrameBuffers {
    rays: Buffer,
    accum: Buffer,
    counters: Buffer,
    /// Samples per chunk.
    chunk: u32,
}

/// The empty-space tables' words (per channel the block table, then per
/// channel the clear distances, four to a word) and where they lie.
struct SkipTable {
    words: Vec<u32>,
    /// Macro-cells per axis.
    blocks: [usize; 3],
    /// Words of one channel's block table, and of its clear distances.
    block_words: usize,
    clear_words: usize,
}

/// The environment as the kernel reads it: kind (0 constant, 1 lat-long),
/// map size, constant radiance, RGB texels.
struct EnvironmentData {
    kind: u32,
    width: u32,
    height: u32,
    constant: [f32; 3],
    texels: Vec<f32>,
}

impl<'a> GpuRenderer<'a> {
    /// Upload `medium`, its light `volumes` (one per light, possibly none)
    /// and `surroundings`, and compile the kernel, for frames seen by
    /// `camera` with `opts`. A grid, environment map or image that does
    /// not fit the device's limits is a [`GpuError::Device`] saying which.
    pub fn new(
        gpu: &'a Gpu,
        medium: &Medium,
        volumes: &[LightVolume],
        surroundings: &Surroundings,
        camera: &Camera,
        opts: Options,
    ) -> Result<Self, GpuError> {
        Self::build(gpu, None, medium, volumes, surroundings, camera, opts)
    }

    /// [`Self::new`] for `scene` (whose medium `medium` is): with `[grid]
    /// interfaces = "sharp"` eye rays follow each region's own index and
    /// refract at the exact surfaces, as the CPU's
    /// [`crate::Renderer::sharp`] (`march_sharp` in `sharp.wgsl`); else
    /// the same as [`Self::new`]. Every shape, index profile and VDB grid
    /// of the CPU's has a GPU form (`eikon_grid::region::gpu_regions`);
    /// shape data larger than a storage binding is a
    /// [`GpuError::TooLarge`].
    pub fn with_scene(
        gpu: &'a Gpu,
        scene: &Scene,
        medium: &Medium,
        volumes: &[LightVolume],
        surroundings: &Surroundings,
        camera: &Camera,
        opts: Options,
    ) -> Result<Self, GpuError> {
        let sharp = (scene.grid.interfaces == Interfaces::Sharp).then_some(scene);
        Self::build(gpu, sharp, medium, volumes, surroundings, camera, opts)
    }

    /// The steps of [`Self::new`], with sharp interfaces when `sharp` is a
    /// scene.
    fn build(
        gpu: &'a Gpu,
        sharp: Option<&Scene>,
        medium: &Medium,
        volumes: &[LightVolume],
        surroundings: &Surroundings,
        camera: &Camera,
        opts: Options,
    ) -> Result<Self, GpuError> {
        Self::check_limits(gpu, medium, surroundings)?;
        let table = sharp.map(gpu_regions);
        let binding = |what: &str, bytes: u64| check_binding(gpu, what, bytes);
        let properties = Properties::new(medium, probe_length(medium));
        let textures = upload_medium(gpu, medium, &properties);
        let lit = upload_volumes(gpu, medium.geometry.dims, volumes);
        let skip_words = skip_table(medium, opts.skip_empty);
        binding("empty-space table", skip_words.words.len() as u64 * 4)?;
        let skip = gpu.storage("empty space", &skip_words.words);
        let environment = environment_data(surroundings);
        binding("environment map", environment.texels.len() as u64 * 4)?;
        let env = gpu.storage("environment", &environment.texels);
        let frame = frame_buffers(gpu, camera)?;
        let mut params = view_params(
            medium,
            surroundings,
            camera,
            &opts,
            (&textures, &skip_words, &environment),
        );
        let (regions, region_data) = match &table {
            Some(t) => {
                params.sharp = 1;
                params.region_count = (t.table.len() - 1) as u32;
                params.sharp_eps = sharp_eps(&medium.geometry) as f32;
                binding(
                    "region table",
                    std::mem::size_of_val(t.table.as_slice()) as u64,
                )?;
                binding(
                    "region shape data",
                    std::mem::size_of_val(t.data.as_slice()) as u64,
                )?;
                (
                    gpu.storage("regions", &t.table),
                    gpu.storage("region shape data", &t.data),
                )
            }
            None => (
                gpu.storage("no regions", &[RegionGpu::default()]),
                gpu.storage("no region shape data", &[[0u32; 4]]),
            ),
        };
        let params = gpu.uniform("view params", &[params]);
        let kinds = table
            .as_ref()
            .map(|t| eikon_grid::region::table_kinds(&t.table));
        let (pipeline, layout) = compile(gpu, kinds)?;
        let single_chunk = frame.chunk >= camera.samples();
        let mut all = textures.textures;
        all.extend(lit.textures);
        let renderer = Self {
            gpu,
            camera: camera.clone(),
            seed: opts.seed,
            pipeline,
            layout,
            params,
            medium_views: textures.views,
            volume_views: lit.views,
            volume_arrays: lit.arrays,
            skip,
            env,
            rays: frame.rays,
            accum: frame.accum,
            counters: frame.counters,
            chunk: frame.chunk,
            single_chunk,
            lit: !volumes.is_empty(),
            regions,
            region_data,
            _textures: all,
        };
        if single_chunk {
            renderer.upload_rays(0, camera.samples());
        }
        Ok(renderer)
    }

    /// The grid against the 3D texture limit, the lights against
    /// [`MAX_LIGHTS`].
    fn check_limits(
        gpu: &Gpu,
        medium: &Medium,
        surroundings: &Surroundings,
    ) -> Result<(), GpuError> {
        let dims = medium.geometry.dims;
        let [nx, ny, nz] = dims;
        let max3d = gpu.device.limits().max_texture_dimension_3d as usize;
        if dims.iter().any(|&d| d > max3d) {
            return Err(too_big(
                gpu,
                format!("the {nx}x{ny}x{nz} grid exceeds the 3D texture limit of {max3d} per axis"),
            ));
        }
        if surroundings.lights.len() > MAX_LIGHTS {
            return Err(too_big(
                gpu,
                format!(
                    "{} lights; the GPU renderer takes at most {MAX_LIGHTS}",
                    surroundings.lights.len()
                ),
            ));
        }
        Ok(())
    }

    /// Device memory, bytes, that [`Self::new`] and then rendering a frame
    /// (read back with its counters) hold at their peak for a render of
    /// `size`: an upper bound of what [`Gpu::peak_bytes`] counts over them.
    /// From the layouts the code allocates with, item by item:
    ///
    /// * per index channel an rgba32float texture, and an rg32float one of
    ///   its interface sides;
    /// * the packed properties (two rgba32float textures) and the emission
    ///   (one, or a single texel without);
    /// * per light volume its fluence and flux arrays, rgba32float each (a
    ///   single dark texel without any volume);
    /// * the empty-space tables (per channel four words per block and a
    ///   byte per cell) with skipping on, else one word;
    /// * the environment map, RGB f32 per texel (one texel if constant);
    /// * the region table (objects and the ambient medium) with sharp
    ///   interfaces, else one placeholder region, and their shapes' data
    ///   (at least one record);
    /// * the eye rays of one chunk of samples (at most 64 MiB, at least one
    ///   sample), the radiance sums, the frame's counters, the uniforms;
    /// * the largest transient: the staging buffer the image is read back
    ///   through, or a frame's per-pass uniforms.
    ///
    /// Not counted: wgpu's own staging of uploads (at most one upload,
    /// 16 MiB slabs for textures, freed once submitted) and drivers'
    /// padding.
    pub fn device_bytes(size: &DeviceSize) -> u64 {
        let buffer = |bytes: u64| bytes.max(MIN_BUFFER_BYTES);
        let dims = size.dims;
        let channels = size.channels as u64;
        let tiny = [1usize, 1, 1];
        let field = texture_bytes(dims, RGBA);
        let mut b = channels * (field + texture_bytes(dims, RG));
        b += 2 * field;
        b += if size.emission {
            field
        } else {
            texture_bytes(tiny, RGBA)
        };
        b += if size.volumes == 0 {
            texture_bytes(tiny, RGBA)
        } else {
            size.volumes as u64 * (1 + size.flux_arrays as u64) * field
        };
        let words = if size.skip_empty {
            let blocks = dims
                .iter()
                .map(|&d| d.div_ceil(BLOCK) as u64)
                .product::<u64>();
            let cells = dims.iter().map(|&d| d as u64).product::<u64>();
            channels * (4 * blocks + cells.div_ceil(4))
        } else {
            1
        };
        b += buffer(words * 4);
        b += buffer(size.environment_texels.max(1) as u64 * PIXEL_BYTES);
        b += buffer((size.regions + 1) as u64 * RegionGpu::size() as u64);
        b += buffer(size.region_data.max(1) as u64 * 16);
        let pixels = u64::from(size.width) * u64::from(size.height);
        let per_sample = pixels * PIXEL_BYTES;
        let chunk = (RAY_CHUNK / per_sample.max(1)).clamp(1, u64::from(size.samples.max(1)));
        b += buffer(per_sample * chunk);
        let accum = buffer(pixels * PIXEL_BYTES);
        b += accum + COUNTER_BYTES;
        b += ViewParams::size() as u64;
        let passes = size.volumes.max(1) as u64;
        b + accum.max(passes * RenderPass::size() as u64)
    }

    /// Write the eye-ray directions of samples `s0..s1` (sample-major,
    /// then pixel rows) into the ray buffer.
    fn upload_rays(&self, s0: u32, s1: u32) {
        let cam = &self.camera;
        let (w, h) = (cam.width(), cam.height());
        let mut dirs = Vec::with_capacity(((s1 - s0) * w * h * 3) as usize);
        for s in s0..s1 {
            for y in 0..h {
                for x in 0..w {
                    let (_, d) = cam.ray(x, y, s, self.seed);
                    dirs.extend([d.x as f32, d.y as f32, d.z as f32]);
                }
            }
        }
        self.gpu
            .queue
            .write_buffer(&self.rays, 0, bytemuck::cast_slice(&dirs));
    }

    /// Submit one frame's work and wait for it.
    fn run_frame(&self) -> Result<(), GpuError> {
        let gpu = self.gpu;
        let cam = &self.camera;
        let n = cam.samples();
        let (gx, gy) = (cam.width().div_ceil(TILE), cam.height().div_ceil(TILE));
        let mut s0 = 0;
        let mut first = true;
        while s0 < n {
            let s1 = (s0 + self.chunk).min(n);
            if !self.single_chunk {
                self.upload_rays(s0, s1);
            }
            gpu.checked("view render", || {
                let mut enc = gpu.device.create_command_encoder(&Default::default());
                if first {
                    enc.clear_buffer(&self.accum, 0, None);
                    enc.clear_buffer(&self.counters, 0, None);
                }
                // Uniform buffers and bind groups live until the submit.
                let mut groups = Vec::new();
                for (j, vol) in self.volume_views.iter().enumerate() {
                    let pass = gpu.uniform(
                        "view pass",
                        &[RenderPass {
                            base: u32::from(j == 0),
                            lit: u32::from(self.lit),
                            flux_arrays: self.volume_arrays[j],
                            samples: s1 - s0,
                        }],
                    );
                    let mut entries = vec![
                        wgpu::BindGroupEntry {
                            binding: 0,
                            resource: self.params.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 1,
                            resource: pass.as_entire_binding(),
                        },
                    ];
                    let views = self.medium_views.iter().chain(vol.iter());
                    for (k, v) in views.enumerate() {
                        entries.push(wgpu::BindGroupEntry {
                            binding: 2 + k as u32,
                            resource: wgpu::BindingResource::TextureView(v),
                        });
                    }
                    let buffers = [
                        &self.skip,
                        &self.env,
                        &self.rays,
                        &self.accum,
                        &self.counters,
                    ];
                    for (b, buf) in buffers.into_iter().enumerate() {
                        entries.push(wgpu::BindGroupEntry {
                            binding: 15 + b as u32,
                            resource: buf.as_entire_binding(),
                        });
                    }
                    entries.push(wgpu::BindGroupEntry {
                        binding: 20,
                        resource: self.regions.as_entire_binding(),
                    });
                    entries.push(wgpu::BindGroupEntry {
                        binding: 21,
                        resource: self.region_data.as_entire_binding(),
                    });
                    let group = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
                        label: Some("view renderer"),
                        layout: &self.layout,
                        entries: &entries,
                    });
                    groups.push((pass, group));
                }
                for (_, group) in &groups {
                    let mut cp = enc.begin_compute_pass(&Default::default());
                    cp.set_pipeline(&self.pipeline);
                    cp.set_bind_group(0, group, &[]);
                    cp.dispatch_workgroups(gx, gy, 1);
                }
                gpu.queue.submit([enc.finish()]);
            })?;
            first = false;
            s0 = s1;
        }
        gpu.wait()
    }

    /// Render one frame (volumes already uploaded); returns the HDR image,
    /// the same struct as the CPU's: per pixel the mean over its samples.
    pub fn render(&self) -> Result<Image, GpuError> {
        self.run_frame()?;
        self.image()
    }

    /// Render one frame as [`Self::render`], with its counters as the CPU
    /// renderer's [`Stats`]: the ray-equation steps and empty-space skips
    /// of the eye rays' paths. Each light volume is a pass that marches
    /// the same paths again; they are counted once, as on the CPU.
    pub fn render_with_stats(&self) -> Result<(Image, Stats), GpuError> {
        self.run_frame()?;
        let image = self.image()?;
        let c: Vec<u32> = self.gpu.read(&self.counters, 4)?;
        let wide = |k: usize| u64::from(c[k]) | (u64::from(c[k + 1]) << 32);
        Ok((
            image,
            Stats {
                steps: wide(0),
                skips: wide(2),
            },
        ))
    }

    /// The last frame's image from the accumulation buffer.
    fn image(&self) -> Result<Image, GpuError> {
        let (w, h) = (self.camera.width(), self.camera.height());
        let sum: Vec<f32> = self.gpu.read(&self.accum, (w * h * 3) as usize)?;
        let n = f64::from(self.camera.samples());
        let data = sum
            .chunks_exact(3)
            .map(|c| [0, 1, 2].map(|k| (f64::from(c[k]) / n) as f32))
            .collect();
        Ok(Image {
            width: w,
            height: h,
            data,
        })
    }

    /// Render `frames` frames back to back and return the mean seconds per
    /// frame measured on the GPU side (submit..done), for benchmarks.
    pub fn time_frames(&self, frames: u32) -> Result<f64, GpuError> {
        let frames = frames.max(1);
        let mut total = 0.0;
        for _ in 0..frames {
            let t = Instant::now();
            self.run_frame()?;
            total += t.elapsed().as_secs_f64();
        }
        Ok(total / f64::from(frames))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The composed source parses and validates as wgpu compiles it, and
    /// its uniform blocks have the Rust structs' offsets (no device
    /// needed).
    #[test]
    fn the_kernel_validates_and_its_layouts_match_rust() {
        for sharp in [false, true] {
            let module =
                eikon_gpu::layout::validate(&source(sharp)).unwrap_or_else(|e| panic!("{e}"));
            eikon_gpu::layout::check::<ViewParams>(&module).unwrap();
            eikon_gpu::layout::check::<ViewLight>(&module).unwrap();
            eikon_gpu::layout::check::<RenderPass>(&module).unwrap();
            eikon_gpu::layout::check::<GridGpu>(&module).unwrap();
            if sharp {
                eikon_gpu::layout::check::<RegionGpu>(&module).unwrap();
            }
        }
    }
    use crate::background::load_environment;
    use eikon_grid::Scene;

    /// Rays uploaded in chunks of one sample give bitwise the image of one
    /// upload (the samples are summed in the same order).
    #[test]
    fn chunked_rays_give_the_same_image() {
        let gpu = match Gpu::new() {
            Ok(g) => g,
            Err(e) => {
                assert!(std::env::var_os("CI").is_none(), "CI needs a GPU: {e}");
                return;
            }
        };
        let scene = Scene::parse(
            r#"
[grid]
resolution = 16
min = [-1, -1, -1]
max = [1, 1, 1]

[[object]]
shape = { type = "sphere", center = [0, 0, 0], radius = 0.6 }
index = 1.4
extinction = [0.3, 0.2, 0.1]

[background]
type = "sky"
"#,
            "test",
        )
        .unwrap();
        let medium = Medium::build(&scene).unwrap();
        let env = load_environment(&scene.background).unwrap();
        let s = Surroundings::new(&scene, env, &[], &medium.geometry);
        let cam = Camera::new(
            glam::DVec3::new(0.2, 0.3, 3.0),
            glam::DVec3::ZERO,
            glam::DVec3::Y,
            40.0,
            20,
            15,
            3,
        )
        .unwrap();
        let opts = Options::default();
        let whole = GpuRenderer::new(&gpu, &medium, &[], &s, &cam, opts).unwrap();
        assert!(whole.single_chunk);
        let mut chunked = GpuRenderer::new(&gpu, &medium, &[], &s, &cam, opts).unwrap();
        chunked.chunk = 1;
        chunked.single_chunk = false;
        let (a, sa) = whole.render_with_stats().unwrap();
        let (b, sb) = chunked.render_with_stats().unwrap();
        assert!(a.data.iter().flatten().any(|&x| x > 0.0));
        assert!(a.data == b.data);
        // The counters sum over the chunks' dispatches, and start again
        // with each frame.
        assert!(sa.steps > 0);
        assert_eq!(sa, sb);
        assert_eq!(whole.render_with_stats().unwrap().1, sa);
    }
}
