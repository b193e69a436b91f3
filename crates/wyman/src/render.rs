//! A frame: the caustic maps of the scene's lights, the eye's refraction
//! passes per pixel sample, and the CPU's shading of the read-back exit
//! rays through the renderer's surroundings.

use crate::caustic::CausticMap;
use crate::gpu::{status, ExitRays, Raster, TARGET_BYTES_PER_PIXEL};
use crate::refractor::Refractor;
use crate::view::View;
use crate::{Settings, WymanError};
use eikon_grid::Scene;
use eikon_optics::fresnel;
use eikon_optics::{Camera, Image};
use eikon_view::Surroundings;
use glam::{DVec2, DVec3};
use rayon::prelude::*;
use std::time::Instant;

/// What a frame did and what it took.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Stats {
    /// Pixel samples the refractor covers.
    pub covered: usize,
    /// Of those, samples whose estimated exit point found no back normal
    /// ([Wyman06 eq 6.3.2] stood in).
    pub fallback_normal: usize,
    /// Samples with total internal reflection at the back surface.
    pub tir_back: usize,
    /// Samples where nothing enters the refractor.
    pub tir_front: usize,
    /// Samples with no back face at their own pixel (`d_V` = 0).
    pub no_back_depth: usize,
    /// Render passes: four per light with a caustic map, three per eye
    /// sample.
    pub passes: usize,
    /// Bytes read back from the device.
    pub readback_bytes: u64,
    /// Lights with a caustic map.
    pub caustic_lights: usize,
    /// Seconds in the caustic maps (passes and readback).
    pub caustic_seconds: f64,
    /// Seconds in the eye's passes and readback.
    pub eye_seconds: f64,
    /// Seconds shading on the CPU.
    pub shade_seconds: f64,
}

/// The caustic and shadow maps of each light of `scene` (none without a
/// receiver plane), with the photon buffer and shadow map at
/// `settings.photons` texels a side.
pub fn caustic_maps(
    raster: &Raster,
    scene: &Scene,
    refractor: &Refractor,
    settings: &Settings,
) -> Result<Vec<CausticMap>, WymanError> {
    let Some(receiver) = &scene.receiver else {
        return Ok(Vec::new());
    };
    let views = light_views(scene, refractor, settings)?;
    if views.is_empty() {
        return Ok(Vec::new());
    }
    let targets = raster.targets([settings.photons; 2])?;
    views
        .into_iter()
        .map(|(photon, caustic)| {
            let (values, shadow) = raster.caustic(
                &photon,
                &caustic,
                (receiver.point, receiver.normal),
                settings,
                &targets,
            )?;
            Ok(CausticMap::new(caustic, photon, values, shadow))
        })
        .collect()
}

/// Each light's photon-buffer and caustic-map views (none without a
/// receiver), or the error naming a light the method cannot take.
fn light_views(
    scene: &Scene,
    refractor: &Refractor,
    settings: &Settings,
) -> Result<Vec<(View, View)>, WymanError> {
    if scene.receiver.is_none() {
        return Ok(Vec::new());
    }
    let (c, r) = refractor.bounding_sphere();
    scene
        .lights
        .iter()
        .enumerate()
        .map(|(i, l)| {
            let photon = View::of_light(l, c, r, 1.0, settings.photons);
            let caustic = View::of_light(l, c, r, settings.caustic_extent, settings.caustic_map);
            match (photon, caustic) {
                (Ok(p), Ok(q)) => Ok((p, q)),
                (Err(e), _) | (_, Err(e)) => Err(e.error(scene, i)),
            }
        })
        .collect()
}

/// The scene's refractor, once every part of the scene the method needs
/// is known to be one it can take (its object, and its lights where there
/// is a receiver to light): the checks of [`render`] that need no device.
pub fn check(scene: &Scene) -> Result<Refractor, WymanError> {
    let refractor = Refractor::from_scene(scene)?;
    light_views(scene, &refractor, &Settings::default())?;
    Ok(refractor)
}

/// Where in its pixel sample `s` of `samples` lies: the centre of the
/// s-th cell of the camera's strata grid, the same offset in every pixel
/// (a rasterizer's jitter), so every pass is one ordinary projection.
pub fn sample_offset(camera: &Camera, s: u32) -> DVec2 {
    let (nx, ny) = camera.strata();
    DVec2::new(
        (f64::from(s % nx) + 0.5) / f64::from(nx),
        (f64::from(s / nx) + 0.5) / f64::from(ny),
    )
}

/// Render `scene` through `camera` on `gpu` by Wyman's image-space
/// refraction and caustic maps (crate docs): the image and what it took.
/// [`Renderer`] keeps the mesh and pipelines for more frames.
pub fn render(
    gpu: &eikon_gpu::Gpu,
    scene: &Scene,
    camera: &Camera,
    settings: &Settings,
) -> Result<(Image, Stats), WymanError> {
    Renderer::new(gpu, scene, settings)?.render(camera)
}

/// A scene ready to render: its refractor on the device, the pipelines,
/// the background loaded.
pub struct Renderer<'a> {
    scene: &'a Scene,
    settings: Settings,
    refractor: Refractor,
    raster: Raster<'a>,
    environment: eikon_optics::Environment,
}

impl<'a> Renderer<'a> {
    /// Check `scene` (refused by field where the method cannot take it),
    /// mesh its object and build the pipelines.
    pub fn new(
        gpu: &'a eikon_gpu::Gpu,
        scene: &'a Scene,
        settings: &Settings,
    ) -> Result<Renderer<'a>, WymanError> {
        let refractor = check(scene)?;
        settings.check(gpu.device.limits().max_texture_dimension_2d)?;
        let environment = eikon_view::background::load_environment(&scene.background)?;
        let raster = Raster::new(gpu, &refractor)?;
        Ok(Renderer {
            scene,
            settings: *settings,
            refractor,
            raster,
            environment,
        })
    }

    /// One frame through `camera`: each light's caustic and shadow maps,
    /// then per pixel sample the eye's passes and the CPU's shading.
    pub fn render(&self, camera: &Camera) -> Result<(Image, Stats), WymanError> {
        let (scene, settings, refractor) = (self.scene, &self.settings, &self.refractor);
        if refractor.contains(camera.position()) {
            return Err(WymanError::Scene(scene.error_at(
                "camera.position",
                "the image-space method (wyman) needs the camera outside the refracting object",
            )));
        }
        let mut stats = Stats::default();
        let started = Instant::now();
        let maps = caustic_maps(&self.raster, scene, refractor, settings)?;
        stats.caustic_seconds = started.elapsed().as_secs_f64();
        stats.caustic_lights = maps.len();
        stats.passes += 4 * maps.len();
        let np = u64::from(settings.photons).pow(2);
        let nc = u64::from(settings.caustic_map).pow(2);
        stats.readback_bytes += maps.len() as u64 * (16 * np + 24 * nc);
        let factor = |j: usize, x: DVec3| maps[j].factor(x);
        let mut surroundings =
            Surroundings::new(scene, self.environment.clone(), &[], &scene.grid.geometry);
        if !maps.is_empty() {
            surroundings = surroundings.with_light_factor(&factor);
        }
        let (w, h) = (camera.width(), camera.height());
        let targets = self.raster.targets([w, h])?;
        let (centre, radius) = refractor.bounding_sphere();
        let mut sum = vec![DVec3::ZERO; (w as usize) * (h as usize)];
        for s in 0..camera.samples() {
            let offset = sample_offset(camera, s);
            let t = Instant::now();
            let view = View::of_camera(camera, offset, centre, radius);
            let rays = self.raster.exit_rays(&view, settings.tir, &targets)?;
            stats.eye_seconds += t.elapsed().as_secs_f64();
            stats.passes += 3;
            stats.readback_bytes += 64 * u64::from(w) * u64::from(h);
            let t = Instant::now();
            shade(
                &rays,
                camera,
                offset,
                &surroundings,
                refractor,
                &mut sum,
                &mut stats,
            );
            stats.shade_seconds += t.elapsed().as_secs_f64();
        }
        let k = 1.0 / f64::from(camera.samples());
        let data = sum.iter().map(|c| (*c * k).as_vec3().to_array()).collect();
        let image = Image::from_data(w, h, data).expect("one pixel per sample");
        Ok((image, stats))
    }

    /// The refractor.
    pub fn refractor(&self) -> &Refractor {
        &self.refractor
    }
}

/// Device bytes a frame holds at its peak: the eye's targets and
/// readback, the light's targets, caustic sums and readback, and the mesh.
pub fn device_bytes(
    refractor_triangles: usize,
    width: u32,
    height: u32,
    settings: &Settings,
) -> u64 {
    let eye = u64::from(width) * u64::from(height);
    let np = u64::from(settings.photons).pow(2);
    let nc = u64::from(settings.caustic_map).pow(2);
    // Rows of a readback are padded to 256 bytes (16 texels).
    let pad = |w: u32, h: u32| u64::from(w.div_ceil(16) * 16) * u64::from(h);
    let mesh = 3 * refractor_triangles as u64 * 32;
    // The eye's readback: four images copied into one buffer, then staged.
    let eye_read = 2 * 4 * 16 * pad(width, height);
    let light = np * TARGET_BYTES_PER_PIXEL
        + nc * (24 + 1)
        + 2 * 24 * nc
        + 2 * 16 * pad(settings.photons, settings.photons);
    mesh + eye * TARGET_BYTES_PER_PIXEL + eye_read.max(light) + 1024
}

/// Shade one sample of every pixel from its exit ray, adding into `sum`.
fn shade(
    rays: &ExitRays,
    camera: &Camera,
    offset: DVec2,
    s: &Surroundings,
    refractor: &Refractor,
    sum: &mut [DVec3],
    stats: &mut Stats,
) {
    let w = camera.width();
    let rows: Vec<Stats> = sum
        .par_chunks_mut(w as usize)
        .enumerate()
        .map(|(py, row)| {
            let mut st = Stats::default();
            let py = py as u32;
            for (px, out) in row.iter_mut().enumerate() {
                let px = px as u32;
                let (eye, d) =
                    camera.ray_through(f64::from(px) + offset.x, f64::from(py) + offset.y);
                *out += match rays.at(px, py) {
                    None => s.radiance(eye, d, 0),
                    Some(e) => {
                        st.covered += 1;
                        let flag = |b: u32| usize::from(e.status & b != 0);
                        st.fallback_normal += flag(status::FALLBACK_NORMAL);
                        st.tir_back += flag(status::TIR_BACK);
                        st.tir_front += flag(status::TIR_FRONT);
                        st.no_back_depth += flag(status::NO_BACK_DEPTH);
                        let to = e.p1 - eye;
                        if s.receiver_hit(eye, d, to.length()).is_some() {
                            // The receiver is nearer than the refractor.
                            s.radiance(eye, d, 0)
                        } else {
                            radiance(&e, to.normalize(), s, refractor)
                        }
                    }
                };
            }
            st
        })
        .collect();
    for r in rows {
        stats.covered += r.covered;
        stats.fallback_normal += r.fallback_normal;
        stats.tir_back += r.tir_back;
        stats.tir_front += r.tir_front;
        stats.no_back_depth += r.no_back_depth;
    }
}

/// Radiance towards the eye along `v` from a refractor pixel: Fresnel
/// reflection of the surroundings at p1, and the surroundings along the
/// exit ray with both interfaces' transmittance and Beer-Lambert over the
/// estimated path inside.
fn radiance(e: &crate::Exit, v: DVec3, s: &Surroundings, refractor: &Refractor) -> DVec3 {
    let front = fresnel::interface(v, e.n1, refractor.outside, refractor.inside);
    let mut l = front.reflectance * s.radiance(e.p1, front.reflected.normalize(), 0);
    if e.status & status::TIR_FRONT == 0 && e.fresnel > 0.0 {
        let k = refractor.extinction * (e.p2 - e.p1).length();
        let through = DVec3::new((-k.x).exp(), (-k.y).exp(), (-k.z).exp());
        l += e.fresnel * through * s.radiance(e.p2, e.t2.normalize(), 0);
    }
    l
}
