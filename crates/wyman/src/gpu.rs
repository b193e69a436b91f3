//! The render pipelines: the refraction passes (`refract.wgsl`) over one
//! view into [`Targets`], the caustic splats (`splat.wgsl`), and the
//! readback of what the CPU shades with.

use crate::refractor::Refractor;
use crate::view::View;
use crate::{Settings, Tir};
use eikon_gpu::{Buffer, Gpu, GpuError, Texture};
use eikon_shader::{compose, layout, Consts, Layout};
use glam::DVec3;

const REFRACT: &str = include_str!("refract.wgsl");
const SPLAT: &str = include_str!("splat.wgsl");

layout! {
    /// The refraction passes' uniform block (`view` in `refract.wgsl`): one
    /// view, the eye's or a light's.
    pub struct ViewUniform {
        /// World to clip space, column-major.
        pub view_proj: [[f32; 4]; 4],
        /// The eye (perspective) or a point behind the scene on the axis
        /// (orthographic).
        pub eye: [f32; 3],
        /// 1: a perspective view, 0: orthographic.
        pub perspective: u32,
        /// The unit view axis.
        pub forward: [f32; 3],
        /// Padding.
        pub pad0: f32,
        /// Target size, pixels.
        pub size: [f32; 2],
        /// The index outside the object.
        pub n_outside: f32,
        /// The index inside it.
        pub n_inside: f32,
        /// What total internal reflection at the back does: `TIR_*`.
        pub tir: u32,
        /// Padding.
        pub pad1: u32,
        /// Padding.
        pub pad2: u32,
        /// Padding.
        pub pad3: u32,
    }
}

layout! {
    /// The caustic splats' uniform block (`sp` in `splat.wgsl`).
    pub struct SplatUniform {
        /// The caustic map's world to clip space (the light's view),
        /// column-major.
        pub view_proj: [[f32; 4]; 4],
        /// A point of the receiver plane.
        pub receiver_point: [f32; 3],
        /// Padding.
        pub pad0: f32,
        /// Its unit normal.
        pub receiver_normal: [f32; 3],
        /// Padding.
        pub pad1: f32,
        /// Extinction inside the refractor, RGB.
        pub extinction: [f32; 3],
        /// Padding.
        pub pad2: f32,
        /// Photon-buffer side, texels.
        pub photon_side: f32,
        /// Caustic-map side, texels.
        pub caustic_side: f32,
        /// Splat side, texels (odd).
        pub splat_side: f32,
        /// Gaussian sigma, caustic texels.
        pub sigma: f32,
        /// Half-extent of the photon buffer's image plane (a tangent for
        /// a pinhole).
        pub photon_half: f32,
        /// Half-extent of the caustic map's.
        pub caustic_half: f32,
        /// 1: a pinhole (point light), 0: orthographic.
        pub pinhole: u32,
        /// The paper's R: caustic texels per photon.
        pub texels_per_photon: f32,
        /// Fixed-point units per 1.0 of the map.
        pub scale: f32,
        /// Padding.
        pub pad3: f32,
        /// Padding.
        pub pad4: f32,
        /// Padding.
        pub pad5: f32,
    }
}

fn refract_declarations() -> String {
    let c = Consts::new()
        .u32("COVERED", status::COVERED)
        .u32("FALLBACK_NORMAL", status::FALLBACK_NORMAL)
        .u32("TIR_BACK", status::TIR_BACK)
        .u32("TIR_FRONT", status::TIR_FRONT)
        .u32("NO_BACK_DEPTH", status::NO_BACK_DEPTH)
        .u32("TIR_SINGLE", Tir::Single as u32)
        .u32("TIR_CLAMP", Tir::Clamp as u32)
        .u32("TIR_REFLECT", Tir::Reflect as u32);
    format!("{}{}", ViewUniform::declaration(), c.wgsl())
}

/// The refraction passes' full WGSL: the view block, the status bits and
/// the shared Fresnel module before `refract.wgsl`.
pub fn refract_source() -> String {
    compose(
        &refract_declarations(),
        &[&eikon_optics::fresnel::WGSL],
        REFRACT,
    )
}

/// The caustic splats' full WGSL.
pub fn splat_source() -> String {
    compose(&SplatUniform::declaration(), &[], SPLAT)
}

/// Format of every colour target of the refraction passes.
const RGBA: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;
/// Depth buffer format.
const DEPTH: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// Bytes per pixel of one view's targets: depth, back, two front, two exit.
pub const TARGET_BYTES_PER_PIXEL: u64 = 4 + 5 * 16;

/// Fixed-point units per 1.0 of the caustic map (2^24: a splat fragment
/// rounds to 6e-8 of the unobstructed light).
pub const CAUSTIC_SCALE: f64 = 16_777_216.0;

/// Words per caustic texel: three channels of (lo, hi).
const WORDS: usize = 6;

/// Exit-ray status bits (`refract.wgsl`).
pub mod status {
    /// The refractor covers the pixel.
    pub const COVERED: u32 = 1;
    /// No back normal where the exit point projects: [Wyman06 eq 6.3.2].
    pub const FALLBACK_NORMAL: u32 = 2;
    /// Total internal reflection at the back ([`crate::Tir`]).
    pub const TIR_BACK: u32 = 4;
    /// Nothing enters (the inside index below the outside's, beyond the
    /// critical angle).
    pub const TIR_FRONT: u32 = 8;
    /// No back face at the pixel itself: `d_V` = 0.
    pub const NO_BACK_DEPTH: u32 = 16;
}

fn f3(v: DVec3) -> [f32; 3] {
    [v.x as f32, v.y as f32, v.z as f32]
}

/// The render targets of one view.
pub struct Targets {
    size: [u32; 2],
    depth: Texture,
    back: Texture,
    front_position: Texture,
    front_normal: Texture,
    exit_position: Texture,
    exit_direction: Texture,
}

/// One pixel's exit, as read back.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Exit {
    /// Front surface point p1.
    pub p1: DVec3,
    /// Its shading normal N1 (towards the viewer).
    pub n1: DVec3,
    /// [`status`] bits.
    pub status: u32,
    /// Where the ray leaves, p2 (p1 when nothing enters).
    pub p2: DVec3,
    /// Unit exit direction T2 (zero when nothing enters).
    pub t2: DVec3,
    /// Fresnel transmittance of both interfaces, (1 - R1)(1 - R2).
    pub fresnel: f64,
}

/// A view's G-buffer and exit rays, read back.
pub struct ExitRays {
    /// The view they were rendered in.
    pub view: View,
    front_position: Vec<[f32; 4]>,
    front_normal: Vec<[f32; 4]>,
    exit_position: Vec<[f32; 4]>,
    exit_direction: Vec<[f32; 4]>,
}

fn d3(v: [f32; 4]) -> DVec3 {
    DVec3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2]))
}

impl ExitRays {
    /// The exit at pixel `(x, y)`, `None` where the refractor is not.
    pub fn at(&self, x: u32, y: u32) -> Option<Exit> {
        let i = (y * self.view.size[0] + x) as usize;
        let n = self.front_normal[i];
        if n[0] * n[0] + n[1] * n[1] + n[2] * n[2] <= 0.25 {
            return None;
        }
        let e = self.exit_position[i];
        let t = self.exit_direction[i];
        Some(Exit {
            p1: d3(self.front_position[i]),
            n1: d3(n),
            status: e[3] as u32,
            p2: d3(e),
            t2: d3(t),
            fresnel: f64::from(t[3]),
        })
    }
}

/// The refractor on the device and the pipelines that draw it.
pub struct Raster<'g> {
    gpu: &'g Gpu,
    back: wgpu::RenderPipeline,
    front: wgpu::RenderPipeline,
    refract: wgpu::RenderPipeline,
    splat: wgpu::RenderPipeline,
    corners: Buffer,
    vertices: u32,
    inside: f64,
    outside: f64,
    extinction: DVec3,
}

fn targets_state(n: usize) -> Vec<Option<wgpu::ColorTargetState>> {
    (0..n).map(|_| Some(RGBA.into())).collect()
}

impl<'g> Raster<'g> {
    /// Upload `refractor` and build the pipelines.
    pub fn new(gpu: &'g Gpu, refractor: &Refractor) -> Result<Raster<'g>, GpuError> {
        let corners = refractor.corners();
        let vertices = u32::try_from(corners.len()).map_err(|_| GpuError::TooLarge {
            what: "the refractor's triangle corners".into(),
            need: corners.len() as u64,
            limit: u64::from(u32::MAX),
            hint: "use a coarser mesh".into(),
        })?;
        let flat: Vec<[f32; 4]> = corners.iter().flatten().copied().collect();
        let corners = gpu.storage("wyman corners", &flat);
        let (back, front, refract, splat) = gpu.checked("wyman pipelines", || {
            let module = |label: &str, src: &str| {
                gpu.device
                    .create_shader_module(wgpu::ShaderModuleDescriptor {
                        label: Some(label),
                        source: wgpu::ShaderSource::Wgsl(src.into()),
                    })
            };
            let refract_module = module("wyman refract", &refract_source());
            let splat_module = module("wyman splat", &splat_source());
            let depth = |compare| {
                Some(wgpu::DepthStencilState {
                    format: DEPTH,
                    depth_write_enabled: true,
                    depth_compare: compare,
                    stencil: Default::default(),
                    bias: Default::default(),
                })
            };
            let surface = |label: &str, fs: &str, cull, compare, outputs: usize| {
                gpu.device
                    .create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                        label: Some(label),
                        layout: None,
                        vertex: wgpu::VertexState {
                            module: &refract_module,
                            entry_point: Some("surface_vs"),
                            compilation_options: Default::default(),
                            buffers: &[],
                        },
                        primitive: wgpu::PrimitiveState {
                            front_face: wgpu::FrontFace::Ccw,
                            cull_mode: Some(cull),
                            ..Default::default()
                        },
                        depth_stencil: depth(compare),
                        multisample: Default::default(),
                        fragment: Some(wgpu::FragmentState {
                            module: &refract_module,
                            entry_point: Some(fs),
                            compilation_options: Default::default(),
                            targets: &targets_state(outputs),
                        }),
                        multiview: None,
                        cache: None,
                    })
            };
            let back = surface(
                "wyman back faces",
                "back_fs",
                wgpu::Face::Front,
                wgpu::CompareFunction::Greater,
                1,
            );
            let front = surface(
                "wyman front faces",
                "front_fs",
                wgpu::Face::Back,
                wgpu::CompareFunction::Less,
                2,
            );
            let refract = fullscreen(gpu, &refract_module, "refract_fs", "wyman refraction", 2);
            let splat = gpu
                .device
                .create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                    label: Some("wyman splats"),
                    layout: None,
                    vertex: wgpu::VertexState {
                        module: &splat_module,
                        entry_point: Some("splat_vs"),
                        compilation_options: Default::default(),
                        buffers: &[],
                    },
                    primitive: Default::default(),
                    depth_stencil: None,
                    multisample: Default::default(),
                    fragment: Some(wgpu::FragmentState {
                        module: &splat_module,
                        entry_point: Some("splat_fs"),
                        compilation_options: Default::default(),
                        // The sums go to a storage buffer; the target
                        // only sets the map's size.
                        targets: &[Some(wgpu::ColorTargetState {
                            format: wgpu::TextureFormat::R8Unorm,
                            blend: None,
                            write_mask: wgpu::ColorWrites::empty(),
                        })],
                    }),
                    multiview: None,
                    cache: None,
                });
            (back, front, refract, splat)
        })?;
        Ok(Raster {
            gpu,
            back,
            front,
            refract,
            splat,
            corners,
            vertices,
            inside: refractor.inside,
            outside: refractor.outside,
            extinction: refractor.extinction,
        })
    }

    /// The device.
    pub fn gpu(&self) -> &'g Gpu {
        self.gpu
    }

    /// Render targets of `size` pixels, refused beyond the device's 2D
    /// texture limit.
    pub fn targets(&self, size: [u32; 2]) -> Result<Targets, GpuError> {
        let limit = self.gpu.device.limits().max_texture_dimension_2d;
        if size[0] > limit || size[1] > limit {
            return Err(GpuError::TooLarge {
                what: format!("a {} x {} render target", size[0], size[1]),
                need: u64::from(size[0].max(size[1])),
                limit: u64::from(limit),
                hint: "render a smaller image or fewer photons".into(),
            });
        }
        let usage = wgpu::TextureUsages::RENDER_ATTACHMENT
            | wgpu::TextureUsages::TEXTURE_BINDING
            | wgpu::TextureUsages::COPY_SRC;
        let tex = |label: &str, format| self.gpu.texture_2d(label, size, format, usage);
        Ok(Targets {
            size,
            depth: tex("wyman depth", DEPTH),
            back: tex("wyman back", RGBA),
            front_position: tex("wyman front position", RGBA),
            front_normal: tex("wyman front normal", RGBA),
            exit_position: tex("wyman exit position", RGBA),
            exit_direction: tex("wyman exit direction", RGBA),
        })
    }

    fn view_block(&self, view: &View, tir: Tir) -> Buffer {
        let m = view.view_proj().as_mat4().to_cols_array_2d();
        let block = ViewUniform {
            view_proj: m,
            eye: f3(view.eye),
            perspective: u32::from(view.perspective),
            forward: f3(view.forward),
            size: [view.size[0] as f32, view.size[1] as f32],
            n_outside: self.outside as f32,
            n_inside: self.inside as f32,
            tir: tir as u32,
            ..Default::default()
        };
        self.gpu.uniform("wyman view", &[block])
    }

    /// Record the three refraction passes of `view` into `targets`.
    fn encode_refraction(
        &self,
        enc: &mut wgpu::CommandEncoder,
        view: &View,
        tir: Tir,
        t: &Targets,
    ) -> Buffer {
        let block = self.view_block(view, tir);
        let bind = |pipe: &wgpu::RenderPipeline, entries: &[(u32, wgpu::BindingResource)]| {
            let entries: Vec<wgpu::BindGroupEntry> = entries
                .iter()
                .map(|(b, r)| wgpu::BindGroupEntry {
                    binding: *b,
                    resource: r.clone(),
                })
                .collect();
            self.gpu
                .device
                .create_bind_group(&wgpu::BindGroupDescriptor {
                    label: None,
                    layout: &pipe.get_bind_group_layout(0),
                    entries: &entries,
                })
        };
        let surface = [
            (0, block.as_entire_binding()),
            (1, self.corners.as_entire_binding()),
        ];
        let back_group = bind(&self.back, &surface);
        let front_group = bind(&self.front, &surface);
        let refract_group = bind(
            &self.refract,
            &[
                (0, block.as_entire_binding()),
                (2, wgpu::BindingResource::TextureView(&t.back.view)),
                (
                    3,
                    wgpu::BindingResource::TextureView(&t.front_position.view),
                ),
                (4, wgpu::BindingResource::TextureView(&t.front_normal.view)),
            ],
        );
        let n = [self.vertices, 1];
        let depth = Some((&t.depth, 0.0));
        pass(
            enc,
            "wyman back faces",
            &self.back,
            &back_group,
            &[&t.back],
            depth,
            n,
        );
        let depth = Some((&t.depth, 1.0));
        let front = [&t.front_position, &t.front_normal];
        pass(
            enc,
            "wyman front faces",
            &self.front,
            &front_group,
            &front,
            depth,
            n,
        );
        let exit = [&t.exit_position, &t.exit_direction];
        pass(
            enc,
            "wyman refraction",
            &self.refract,
            &refract_group,
            &exit,
            None,
            [3, 1],
        );
        block
    }

    /// Render `view`'s three refraction passes into `targets` and read its
    /// G-buffer and exit rays back.
    pub fn exit_rays(&self, view: &View, tir: Tir, t: &Targets) -> Result<ExitRays, GpuError> {
        assert_eq!(view.size, t.size, "targets of the view's size");
        let mut enc = self.gpu.device.create_command_encoder(&Default::default());
        let _block = self.gpu.checked("wyman refraction passes", || {
            let b = self.encode_refraction(&mut enc, view, tir, t);
            self.gpu.submit([enc.finish()]);
            b
        })?;
        let mut images = read_rgba(
            self.gpu,
            &[
                &t.front_position,
                &t.front_normal,
                &t.exit_position,
                &t.exit_direction,
            ],
            t.size,
        )?
        .into_iter();
        let mut next = || images.next().expect("four images");
        Ok(ExitRays {
            view: *view,
            front_position: next(),
            front_normal: next(),
            exit_position: next(),
            exit_direction: next(),
        })
    }

    /// The caustic map and shadow map of one light: the refraction passes
    /// in `photon_view` into `t`, then every photon splatted where its exit
    /// ray meets the receiver plane `(point, normal)` into the caustic map
    /// of `caustic_view`. Returns the map's RGB values (relative to the
    /// unobstructed light, row-major, `caustic_map^2`) and the shadow map
    /// (view distance of the front surface per texel, `None` where
    /// nothing is).
    pub fn caustic(
        &self,
        photon_view: &View,
        caustic_view: &View,
        receiver: (DVec3, DVec3),
        settings: &Settings,
        t: &Targets,
    ) -> Result<(Vec<DVec3>, Vec<Option<f32>>), GpuError> {
        assert_eq!(photon_view.size, t.size, "targets of the view's size");
        let nc = settings.caustic_map;
        let texels = (nc as usize) * (nc as usize);
        let sums = self
            .gpu
            .storage_empty("wyman caustic sums", (texels * WORDS * 4) as u64);
        let dummy = self.gpu.texture_2d(
            "wyman caustic map",
            [nc, nc],
            wgpu::TextureFormat::R8Unorm,
            wgpu::TextureUsages::RENDER_ATTACHMENT,
        );
        let block = SplatUniform {
            view_proj: caustic_view.view_proj().as_mat4().to_cols_array_2d(),
            receiver_point: f3(receiver.0),
            receiver_normal: f3(receiver.1),
            extinction: f3(self.extinction),
            photon_side: settings.photons as f32,
            caustic_side: nc as f32,
            splat_side: settings.splat as f32,
            sigma: settings.splat_sigma() as f32,
            photon_half: photon_view.half.x as f32,
            caustic_half: caustic_view.half.x as f32,
            pinhole: u32::from(photon_view.perspective),
            texels_per_photon: settings.texels_per_photon() as f32,
            scale: CAUSTIC_SCALE as f32,
            ..Default::default()
        };
        let block = self.gpu.uniform("wyman splat", &[block]);
        let mut enc = self.gpu.device.create_command_encoder(&Default::default());
        let _view_block = self.gpu.checked("wyman caustic passes", || {
            let b = self.encode_refraction(&mut enc, photon_view, settings.tir, t);
            enc.clear_buffer(&sums, 0, None);
            let group = self
                .gpu
                .device
                .create_bind_group(&wgpu::BindGroupDescriptor {
                    label: None,
                    layout: &self.splat.get_bind_group_layout(0),
                    entries: &[
                        wgpu::BindGroupEntry {
                            binding: 0,
                            resource: block.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 1,
                            resource: wgpu::BindingResource::TextureView(&t.exit_position.view),
                        },
                        wgpu::BindGroupEntry {
                            binding: 2,
                            resource: wgpu::BindingResource::TextureView(&t.exit_direction.view),
                        },
                        wgpu::BindGroupEntry {
                            binding: 3,
                            resource: wgpu::BindingResource::TextureView(&t.front_position.view),
                        },
                        wgpu::BindGroupEntry {
                            binding: 4,
                            resource: sums.as_entire_binding(),
                        },
                    ],
                });
            let photons = settings.photons * settings.photons;
            let (pipe, label) = (&self.splat, "wyman splats");
            pass(&mut enc, label, pipe, &group, &[&dummy], None, [6, photons]);
            self.gpu.submit([enc.finish()]);
            b
        })?;
        let words: Vec<u32> = self.gpu.read(&sums, texels * WORDS)?;
        let values = words
            .chunks_exact(WORDS)
            .map(|w| {
                let v = |k: usize| {
                    (f64::from(w[2 * k + 1]) * 4_294_967_296.0 + f64::from(w[2 * k]))
                        / CAUSTIC_SCALE
                };
                DVec3::new(v(0), v(1), v(2))
            })
            .collect();
        let normals = read_rgba(self.gpu, &[&t.front_normal], t.size)?;
        let shadow = normals[0]
            .iter()
            .map(|n| (n[0] * n[0] + n[1] * n[1] + n[2] * n[2] > 0.25).then_some(n[3]))
            .collect();
        Ok((values, shadow))
    }
}

/// A pipeline of the full-screen triangle and fragment entry `fs` with
/// `outputs` colour targets.
fn fullscreen(
    gpu: &Gpu,
    module: &wgpu::ShaderModule,
    fs: &str,
    label: &str,
    outputs: usize,
) -> wgpu::RenderPipeline {
    gpu.device
        .create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some(label),
            layout: None,
            vertex: wgpu::VertexState {
                module,
                entry_point: Some("fullscreen_vs"),
                compilation_options: Default::default(),
                buffers: &[],
            },
            primitive: Default::default(),
            depth_stencil: None,
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module,
                entry_point: Some(fs),
                compilation_options: Default::default(),
                targets: &targets_state(outputs),
            }),
            multiview: None,
            cache: None,
        })
}

/// Record a render pass of `pipe` with bind group 0 `group`, drawing
/// `[vertices, instances]` into `targets` (cleared to zero), depth-tested
/// against a buffer cleared to the value given.
fn pass(
    enc: &mut wgpu::CommandEncoder,
    label: &str,
    pipe: &wgpu::RenderPipeline,
    group: &wgpu::BindGroup,
    targets: &[&Texture],
    depth: Option<(&Texture, f32)>,
    [vertices, instances]: [u32; 2],
) {
    let colors: Vec<_> = targets.iter().map(|t| Some(clear(t))).collect();
    let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some(label),
        color_attachments: &colors,
        depth_stencil_attachment: depth.map(|(t, value)| wgpu::RenderPassDepthStencilAttachment {
            view: &t.view,
            depth_ops: Some(wgpu::Operations {
                load: wgpu::LoadOp::Clear(value),
                store: wgpu::StoreOp::Store,
            }),
            stencil_ops: None,
        }),
        ..Default::default()
    });
    pass.set_pipeline(pipe);
    pass.set_bind_group(0, group, &[]);
    pass.draw(0..vertices, 0..instances);
}

/// A colour attachment cleared to zero and kept.
fn clear(tex: &Texture) -> wgpu::RenderPassColorAttachment<'_> {
    wgpu::RenderPassColorAttachment {
        view: &tex.view,
        resolve_target: None,
        ops: wgpu::Operations {
            load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
            store: wgpu::StoreOp::Store,
        },
    }
}

/// Bytes of a texture row in a copy: 16 bytes a texel, padded to wgpu's
/// 256-byte row alignment.
fn row_bytes(width: u32) -> u64 {
    let align = u64::from(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
    (u64::from(width) * 16).div_ceil(align) * align
}

/// Read `rgba32float` textures of `size` back, each as row-major texels.
fn read_rgba(
    gpu: &Gpu,
    textures: &[&Texture],
    size: [u32; 2],
) -> Result<Vec<Vec<[f32; 4]>>, GpuError> {
    let row = row_bytes(size[0]);
    let each = row * u64::from(size[1]);
    let buffer = gpu.storage_empty("wyman readback", each * textures.len() as u64);
    gpu.checked("wyman readback", || {
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        for (k, t) in textures.iter().enumerate() {
            enc.copy_texture_to_buffer(
                t.as_image_copy(),
                wgpu::TexelCopyBufferInfo {
                    buffer: &buffer,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: each * k as u64,
                        bytes_per_row: Some(row as u32),
                        rows_per_image: Some(size[1]),
                    },
                },
                wgpu::Extent3d {
                    width: size[0],
                    height: size[1],
                    depth_or_array_layers: 1,
                },
            );
        }
        gpu.submit([enc.finish()]);
    })?;
    let floats: Vec<[f32; 4]> = gpu.read(&buffer, (each / 16) as usize * textures.len())?;
    let per_row = (row / 16) as usize;
    let (w, h) = (size[0] as usize, size[1] as usize);
    Ok((0..textures.len())
        .map(|k| {
            let base = k * per_row * h;
            (0..h)
                .flat_map(|y| {
                    floats[base + y * per_row..base + y * per_row + w]
                        .iter()
                        .copied()
                })
                .collect()
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Both shaders parse and validate as wgpu compiles them, and their
    /// uniform blocks have the Rust structs' offsets (no device needed).
    #[test]
    fn the_shaders_validate_and_their_layouts_match_rust() {
        let refract =
            eikon_gpu::layout::validate(&refract_source()).unwrap_or_else(|e| panic!("{e}"));
        eikon_gpu::layout::check::<ViewUniform>(&refract).unwrap();
        let splat = eikon_gpu::layout::validate(&splat_source()).unwrap_or_else(|e| panic!("{e}"));
        eikon_gpu::layout::check::<SplatUniform>(&splat).unwrap();
    }
}
