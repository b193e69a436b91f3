//! Exact single scattering in a homogeneous medium bounded by a closed
//! triangle mesh: Walter et al. 2009 (point sampling along the refracted
//! camera ray, refracted connections found by [`crate::walter`] through the
//! position-normal tree) and Holzschuch 2015 (per-triangle integration along
//! the refracted camera segment, [`crate::holzschuch`]), with a
//! straight-line baseline that ignores refraction on the light side.
//!
//! # Image formation
//!
//! A camera ray (from outside the medium) that hits the mesh splits by
//! Fresnel at the shading normal: the reflected part sees the background,
//! the transmitted part refracts inside and runs straight to the exit point
//! (the segment `[A, B]`, length `s`). Along it,
//!
//! `L_ss = T_in ∫₀ˢ σ_s e^{−σ_t t} Σ_lights Σ_paths I F e^{−σ_t d_V} ρ / D dt`
//!
//! where the inner sum is [Walter09 eq 17] over the refracted paths
//! `L → P → V(t)`. The `η²` of radiance inside and the `1/η²` of leaving it
//! towards the eye cancel (see [`crate::walter`]). At the exit point the
//! segment refracts out (Fresnel `T_out`, total internal reflection drops
//! it) and sees the background attenuated by `e^{−σ_t s}`. Internal
//! reflections and multiple scattering are not followed.
//!
//! Paths are tested for occlusion: `V → P` must stay inside (no boundary in
//! between), and `P → L` must not cross the mesh again.
//!
//! # Methods
//!
//! * [`Method::Walter`]: `N` samples at the midpoints of `N` equal pieces
//!   of `[0, s]`, each connected to each light point through the
//!   [`PnTree`] and the solver.
//! * [`Method::Holzschuch`]: candidate triangles for the whole segment from
//!   [`PnTree::query_segment`], then [`holzschuch::integrate_triangle`] with
//!   `K` samples per piece.
//! * [`Method::Straight`]: `N` midpoints as for Walter, each connected to
//!   the light by the straight segment, with Fresnel transmittance at its
//!   single crossing and `D = ‖L − V‖²` (refraction ignored).
//!
//! Rendering is parallel over rows with rayon; every pixel depends only on
//! its own rays, so the image is identical whatever the thread count.

use crate::holzschuch::{self, Counters};
use crate::walter::{self, Mode, PnTree, Solution, TreeStats};
use eikon_mesh::{Bvh, Mesh, MeshError, Ray};
use eikon_optics::image::Image;
use eikon_optics::{fresnel, phase, Camera};
use glam::DVec3;
use rayon::prelude::*;
use std::sync::atomic::{AtomicUsize, Ordering};

/// How scatter points along the refracted camera segment are chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// Walter et al. 2009: `samples` points per segment.
    Walter {
        /// Points per segment.
        samples: usize,
    },
    /// Holzschuch 2015: `samples` points per piece of each triangle's
    /// interval (the paper uses 1).
    Holzschuch {
        /// Points per piece.
        samples: usize,
    },
    /// Straight shadow rays (refraction on the light side ignored):
    /// `samples` points per segment.
    Straight {
        /// Points per segment.
        samples: usize,
    },
}

/// A light outside the medium.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MeshLight {
    /// Isotropic point light of total power `power` (intensity `power/4π`).
    Point {
        /// Position.
        position: DVec3,
        /// Power per channel.
        power: DVec3,
    },
    /// Parallel light travelling along `direction` with `irradiance` on a
    /// plane perpendicular to it; modelled as a point far away
    /// ([`DIRECTIONAL_DISTANCE`] times the mesh's size).
    Directional {
        /// Direction of travel.
        direction: DVec3,
        /// Irradiance per channel.
        irradiance: DVec3,
    },
    /// A ball of isotropic emitters: `samples` point lights spread over the
    /// ball (deterministic spiral), sharing `power`.
    Sphere {
        /// Centre.
        center: DVec3,
        /// Radius.
        radius: f64,
        /// Total power per channel.
        power: DVec3,
        /// Point lights used.
        samples: usize,
    },
}

/// Distance of a directional light's stand-in point, in mesh diagonals.
pub const DIRECTIONAL_DISTANCE: f64 = 1e5;

/// Why a medium cannot be built.
#[derive(Debug, thiserror::Error)]
pub enum MediumError {
    /// The boundary is not a closed, outward, manifold mesh (or is bad in
    /// some other way).
    #[error("medium boundary: {0}")]
    Mesh(#[from] MeshError),
    /// A material parameter is out of range.
    #[error("medium parameter {name} = {value}: {reason}")]
    Parameter {
        /// Which.
        name: &'static str,
        /// Its value, formatted.
        value: String,
        /// What it must be.
        reason: &'static str,
    },
}

/// A homogeneous medium inside a closed mesh.
#[derive(Debug, Clone)]
pub struct MeshMedium {
    /// Boundary, outward normals.
    pub mesh: Mesh,
    /// Refractive index relative to the outside.
    pub index: f64,
    /// Extinction `σ_t` per channel (1/length).
    pub extinction: DVec3,
    /// Single-scattering albedo per channel (`σ_s = albedo σ_t`).
    pub albedo: DVec3,
    /// Henyey-Greenstein asymmetry.
    pub g: f64,
    bvh: Bvh,
    tree: PnTree,
    scale: f64,
    flat: bool,
}

impl MeshMedium {
    /// Checks the mesh (closed, manifold, oriented, outward) and the
    /// parameters, and builds the BVH and the position-normal tree.
    pub fn new(
        mesh: Mesh,
        index: f64,
        extinction: DVec3,
        albedo: DVec3,
        g: f64,
    ) -> Result<MeshMedium, MediumError> {
        let bad = |name, value: String, reason| MediumError::Parameter {
            name,
            value,
            reason,
        };
        if !(index.is_finite() && index > 0.0) {
            return Err(bad(
                "index",
                index.to_string(),
                "must be finite and positive",
            ));
        }
        if !(extinction.is_finite() && extinction.min_element() >= 0.0) {
            return Err(bad(
                "extinction",
                format!("{extinction:?}"),
                "must be finite and non-negative",
            ));
        }
        if !(albedo.is_finite() && albedo.min_element() >= 0.0 && albedo.max_element() <= 1.0) {
            return Err(bad("albedo", format!("{albedo:?}"), "must lie in [0, 1]"));
        }
        if !(g.is_finite() && g.abs() < 1.0) {
            return Err(bad("g", g.to_string(), "must lie in (-1, 1)"));
        }
        mesh.require_closed()?;
        let bvh = Bvh::new(&mesh);
        let tree = PnTree::new(walter::mesh_triangles(&mesh));
        let (lo, hi) = mesh.bounds();
        let scale = (hi - lo).length().max(1e-300);
        Ok(MeshMedium {
            mesh,
            index,
            extinction,
            albedo,
            g,
            bvh,
            tree,
            scale,
            flat: false,
        })
    }

    /// The same medium with faceted shading: every triangle uses its
    /// geometric normal (for refraction, Fresnel and the solver), as for a
    /// box whose shared corner vertices carry diagonal normals.
    pub fn faceted(mut self) -> MeshMedium {
        let tris = walter::mesh_triangles(&self.mesh)
            .into_iter()
            .map(|t| walter::Triangle::flat(t.p[0], t.p[1], t.p[2]))
            .collect();
        self.tree = PnTree::new(tris);
        self.flat = true;
        self
    }

    /// Whether [`faceted`](Self::faceted) shading is on.
    pub fn is_faceted(&self) -> bool {
        self.flat
    }

    /// The ray-casting hierarchy.
    pub fn bvh(&self) -> &Bvh {
        &self.bvh
    }

    /// The position-normal tree.
    pub fn tree(&self) -> &PnTree {
        &self.tree
    }

    /// Diagonal of the mesh's bounding box.
    pub fn scale(&self) -> f64 {
        self.scale
    }

    /// The lights as point lights `(position, intensity)`.
    pub fn light_points(&self, lights: &[MeshLight]) -> Vec<(DVec3, DVec3)> {
        let (lo, hi) = self.mesh.bounds();
        let centre = 0.5 * (lo + hi);
        let mut out = Vec::new();
        for l in lights {
            match *l {
                MeshLight::Point { position, power } => {
                    out.push((position, power / (4.0 * std::f64::consts::PI)))
                }
                MeshLight::Directional {
                    direction,
                    irradiance,
                } => {
                    let r = DIRECTIONAL_DISTANCE * self.scale;
                    out.push((centre - direction.normalize() * r, irradiance * r * r));
                }
                MeshLight::Sphere {
                    center,
                    radius,
                    power,
                    samples,
                } => {
                    let n = samples.max(1);
                    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
                    for i in 0..n {
                        let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
                        let rho = (1.0 - z * z).max(0.0).sqrt();
                        let phi = golden * i as f64;
                        let dir = DVec3::new(rho * phi.cos(), rho * phi.sin(), z);
                        let r = radius * ((i as f64 + 0.5) / n as f64).cbrt();
                        out.push((
                            center + dir * r,
                            power / (4.0 * std::f64::consts::PI * n as f64),
                        ));
                    }
                }
            }
        }
        out
    }
}

/// Work counters of a render.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Stats {
    /// Camera rays traced.
    pub camera_rays: usize,
    /// Camera rays that entered the medium.
    pub entered: usize,
    /// Scatter points (Walter, Straight) or samples (Holzschuch).
    pub scatter_points: usize,
    /// Triangles handed to the solver (or to the integrator).
    pub candidates: usize,
    /// Refracted paths found (before occlusion).
    pub paths: usize,
    /// Paths rejected as occluded.
    pub occluded: usize,
    /// Position-normal tree counters.
    pub tree: TreeStats,
    /// Holzschuch counters.
    pub holzschuch: Counters,
    /// Wall-clock seconds.
    pub seconds: f64,
}

impl Stats {
    fn add(&mut self, o: &Stats) {
        self.camera_rays += o.camera_rays;
        self.entered += o.entered;
        self.scatter_points += o.scatter_points;
        self.candidates += o.candidates;
        self.paths += o.paths;
        self.occluded += o.occluded;
        self.tree += o.tree;
        self.holzschuch += o.holzschuch;
    }
}

/// Solver and sampling settings beyond the [`Method`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Settings {
    /// Solver mode for smooth triangles.
    pub mode: Mode,
    /// Seed of the sub-pixel pattern (with more than one camera sample).
    pub seed: u64,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            mode: Mode::Heuristic,
            seed: 0,
        }
    }
}

/// Renders single scattering in `medium` lit by `lights`, seen from
/// `camera`; `background(direction)` is the radiance arriving from far away
/// along a direction. `progress(rows_done, rows)` is called as rows finish.
pub fn render(
    medium: &MeshMedium,
    lights: &[MeshLight],
    camera: &Camera,
    background: &(dyn Fn(DVec3) -> DVec3 + Sync),
    method: Method,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> (Image, Stats) {
    render_with(
        medium,
        lights,
        camera,
        background,
        method,
        &Settings::default(),
        progress,
    )
}

/// [`render`] with explicit [`Settings`].
pub fn render_with(
    medium: &MeshMedium,
    lights: &[MeshLight],
    camera: &Camera,
    background: &(dyn Fn(DVec3) -> DVec3 + Sync),
    method: Method,
    settings: &Settings,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> (Image, Stats) {
    let start = std::time::Instant::now();
    let points = medium.light_points(lights);
    let (w, h) = (camera.width(), camera.height());
    let done = AtomicUsize::new(0);
    let rows: Vec<(Vec<[f32; 3]>, Stats)> = (0..h)
        .into_par_iter()
        .map(|py| {
            let mut stats = Stats::default();
            let mut row = Vec::with_capacity(w as usize);
            for px in 0..w {
                let n = camera.samples().max(1);
                let mut sum = DVec3::ZERO;
                for s in 0..n {
                    let (o, d) = if n == 1 {
                        camera.center_ray(px, py)
                    } else {
                        camera.ray(px, py, s, settings.seed)
                    };
                    sum += radiance(
                        medium, &points, o, d, background, method, settings, &mut stats,
                    );
                }
                let c = sum / f64::from(n);
                row.push([c.x as f32, c.y as f32, c.z as f32]);
            }
            let k = done.fetch_add(1, Ordering::Relaxed) + 1;
            progress(k, h as usize);
            (row, stats)
        })
        .collect();
    let mut stats = Stats::default();
    let mut data = Vec::with_capacity((w * h) as usize);
    for (row, s) in rows {
        data.extend(row);
        stats.add(&s);
    }
    stats.seconds = start.elapsed().as_secs_f64();
    let image = Image::from_data(w, h, data).expect("row lengths match the camera");
    (image, stats)
}

fn exp3(v: DVec3) -> DVec3 {
    DVec3::new(v.x.exp(), v.y.exp(), v.z.exp())
}

/// Radiance along one camera ray `o + t d` (`d` unit) starting outside.
#[allow(clippy::too_many_arguments)]
pub fn radiance(
    medium: &MeshMedium,
    points: &[(DVec3, DVec3)],
    o: DVec3,
    d: DVec3,
    background: &(dyn Fn(DVec3) -> DVec3 + Sync),
    method: Method,
    settings: &Settings,
    stats: &mut Stats,
) -> DVec3 {
    stats.camera_rays += 1;
    let Some(hit) = medium.bvh.closest_hit(&Ray::new(o, d)) else {
        return background(d);
    };
    if !hit.entering(d) {
        // The camera is inside or the ray grazes from behind: not modelled.
        return background(d);
    }
    let eta = medium.index;
    let n = if !medium.flat && hit.normal.dot(d) < 0.0 {
        hit.normal
    } else {
        hit.geometric_normal
    };
    let iface = fresnel::interface(d, n, 1.0, eta);
    let mut color = iface.reflectance * background(iface.reflected.normalize());
    let Some(din) = iface.refracted else {
        return color;
    };
    if din.dot(hit.geometric_normal) >= 0.0 {
        return color;
    }
    let eps = 1e-9 * medium.scale;
    let Some(exit) = medium
        .bvh
        .closest_hit(&Ray::segment(hit.point, din, eps, f64::INFINITY))
    else {
        return color;
    };
    stats.entered += 1;
    let t_in = 1.0 - iface.reflectance;
    let a = hit.point;
    let len = exit.t;
    let sigma_t = medium.extinction;
    let sigma_s = medium.albedo * sigma_t;
    let scatter = if sigma_s.max_element() > 0.0 {
        in_scatter(medium, points, a, din, len, method, settings, stats)
    } else {
        DVec3::ZERO
    };
    color += t_in * sigma_s * scatter;
    // Transmitted background through the exit point.
    let ne = if !medium.flat && exit.normal.dot(din) > 0.0 {
        exit.normal
    } else {
        exit.geometric_normal
    };
    let out = fresnel::interface(din, ne, eta, 1.0);
    if let Some(dout) = out.refracted {
        color += t_in * (1.0 - out.reflectance) * exp3(-sigma_t * len) * background(dout);
    }
    color
}

/// Whether the path `L → P → V` is blocked: `V → P` must not meet the
/// boundary before `P`, `P → L` must not meet it at all.
fn occluded(medium: &MeshMedium, v: DVec3, sol: &Solution) -> bool {
    let eps = 1e-7 * medium.scale;
    if sol.d_v > 2.0 * eps
        && medium
            .bvh
            .any_hit(&Ray::segment(v, -sol.omega_v, 0.0, sol.d_v - eps))
    {
        return true;
    }
    medium
        .bvh
        .any_hit(&Ray::segment(sol.point, sol.omega_l, eps, sol.d_l))
}

/// `∫₀^len e^{−σ_t t} Σ I F e^{−σ_t d_V} ρ / D dt` per channel (without
/// `σ_s` and `T_in`).
#[allow(clippy::too_many_arguments)]
fn in_scatter(
    medium: &MeshMedium,
    points: &[(DVec3, DVec3)],
    a: DVec3,
    din: DVec3,
    len: f64,
    method: Method,
    settings: &Settings,
    stats: &mut Stats,
) -> DVec3 {
    let eta = medium.index;
    let sigma_t = medium.extinction;
    let wmedium = walter::Medium {
        eta,
        sigma_t: 0.0,
        g: medium.g,
    };
    let toward_eye = -din;
    let tris = medium.tree.triangles();
    let opts = walter::Options::new(settings.mode);
    let mut total = DVec3::ZERO;
    match method {
        Method::Walter { samples } | Method::Straight { samples } => {
            let n = samples.max(1);
            let dt = len / n as f64;
            let mut scratch = Vec::new();
            for i in 0..n {
                let t = (i as f64 + 0.5) * dt;
                let v = a + t * din;
                stats.scatter_points += 1;
                for &(l, intensity) in points {
                    if let Method::Straight { .. } = method {
                        total += dt * straight(medium, v, t, l, intensity, toward_eye, stats);
                        continue;
                    }
                    let (paths, ts) =
                        walter::solve_mesh(&medium.tree, v, l, eta, &opts, &mut scratch);
                    stats.tree += ts;
                    stats.candidates += scratch.len();
                    for (k, sol) in paths {
                        stats.paths += 1;
                        if occluded(medium, v, &sol) {
                            stats.occluded += 1;
                            continue;
                        }
                        let c = walter::contribution(
                            &tris[k as usize],
                            &sol,
                            &wmedium,
                            1.0,
                            toward_eye,
                        );
                        total += dt * intensity * c.value * exp3(-sigma_t * (sol.d_v + t));
                    }
                }
            }
        }
        Method::Holzschuch { samples } => {
            let b = a + len * din;
            let mut cand = Vec::new();
            for &(l, intensity) in points {
                cand.clear();
                stats.tree += medium.tree.query_segment(a, b, l, eta, &mut cand);
                cand.sort_unstable();
                stats.candidates += cand.len();
                for &k in &cand {
                    let tri = &tris[k as usize];
                    let mut counters = Counters::default();
                    let mut paths = 0;
                    let mut occ = 0;
                    let sum = holzschuch::integrate_triangle(
                        tri,
                        a,
                        din,
                        len,
                        l,
                        eta,
                        samples,
                        settings.mode,
                        DVec3::ZERO,
                        &mut counters,
                        |t, sol| {
                            paths += 1;
                            let v = a + t * din;
                            if occluded(medium, v, sol) {
                                occ += 1;
                                return DVec3::ZERO;
                            }
                            let c = walter::contribution(tri, sol, &wmedium, 1.0, toward_eye);
                            intensity * c.value * exp3(-sigma_t * (sol.d_v + t))
                        },
                    );
                    stats.paths += paths;
                    stats.occluded += occ;
                    stats.scatter_points += counters.solves;
                    stats.holzschuch += counters;
                    total += sum;
                }
            }
        }
    }
    total
}

/// The straight-line baseline at `V = A + t ĉ`: the segment to the light
/// must cross the boundary exactly once; Fresnel transmittance there
/// (incidence on the shading normal), `D = ‖L − V‖²`.
fn straight(
    medium: &MeshMedium,
    v: DVec3,
    t: f64,
    l: DVec3,
    intensity: DVec3,
    toward_eye: DVec3,
    stats: &mut Stats,
) -> DVec3 {
    let w = l - v;
    let dist = w.length();
    let dir = w / dist;
    let Some(hit) = medium.bvh.closest_hit(&Ray::segment(v, dir, 0.0, dist)) else {
        return DVec3::ZERO;
    };
    stats.paths += 1;
    let eps = 1e-7 * medium.scale;
    if medium
        .bvh
        .any_hit(&Ray::segment(hit.point, dir, eps, dist - hit.t))
    {
        stats.occluded += 1;
        return DVec3::ZERO;
    }
    let n = if medium.flat {
        hit.geometric_normal
    } else {
        hit.normal
    };
    let f = fresnel::transmittance(dir.dot(n), 1.0, medium.index);
    let rho = phase::hg(-dir.dot(toward_eye), medium.g);
    intensity * f * rho / (dist * dist) * exp3(-medium.extinction * (hit.t + t))
}
