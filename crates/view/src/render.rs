//! The view renderer [Ihrke07 sec 5.3]: curved eye rays through the volume,
//! radiance by the simplified image formation model [Ihrke07 eqs 1-7].
//!
//! Each eye ray enters the volume bounds and is marched with the
//! equal-distance ray equation ([Ihrke07 eqs 9-10]; Euler's [Ihrke07 eqs 11-12]
//! by default, RK4 as an option). Over each step of length `ds` the medium is
//! taken as constant at the step's start, and [Ihrke07 eq 1] is integrated
//! exactly for that piece:
//!
//! * the source `S = albedo sigma_t sum_j p(l_j . -d, g mu_j) phi_j + L_e`
//!   [Ihrke07 eqs 2, 3, 6]: in-scatter from every light volume `j` (fluence
//!   rate `phi_j`, net flux direction `l_j` and mean cosine `mu_j`, see
//!   [`eikon_wavefront::volume`]) through the Henyey-Greenstein phase, plus
//!   emission; it adds `alpha S (1 - exp(-sigma_t ds)) / sigma_t`;
//! * the attenuation `alpha` [Ihrke07 eq 5] is multiplied by
//!   `exp(-sigma_t ds)`;
//! * at a boundary (the indicator `delta`, [Ihrke07 eq 2]) a fraction
//!   `w = delta ds |cos i|` of one crossing is taken in this step (over a
//!   whole crossing `w` sums to 1): it adds `alpha w rho L_r`, with
//!   `rho` the Fresnel reflectance between the index on either side of the
//!   interface and `L_r` the surroundings seen in the mirror direction
//!   (the paper's environment mapping), and multiplies `alpha` by
//!   `(1 - rho)^w`, the Fresnel transmission `tau` of [Ihrke07 eq 5]'s `T(t)`.
//!   Refraction and total internal reflection need no such term: the
//!   ray equation bends the ray through the smoothed interface itself, so
//!   where the interface reflects totally `rho` is taken as 0.
//!
//! A ray that leaves the volume sees the surroundings along its exit
//! direction ([`Surroundings`]): the receiver plane, a checkerboard or the
//! environment. A ray that meets the receiver inside the volume stops
//! there. With three index fields (dispersion) every colour channel
//! traces its own ray.
//!
//! Empty space is skipped: in a uniform macro-cell ([`MacroCells`]:
//! constant index, no gradient, nothing scatters, emits or reflects,
//! constant extinction) a ray goes straight to the block's far side in one
//! step, attenuated exactly by `exp(-sigma_t length)`; elsewhere a
//! per-voxel clear distance lets it step straight as far as such a medium
//! is known to extend around it.

use crate::background::{LightSample, Surroundings};
use crate::macrocell::MacroCells;
use crate::properties::{Properties, Sample};
use eikon_grid::ray::{step_euler_sampled, step_rk4};
use eikon_grid::region::{Regions, SharpRay};
use eikon_grid::{CameraSettings, Form, IndexField, Integrator, Medium, Progress, RayState, Scene};
use eikon_optics::phase::hg;
use eikon_optics::{fresnel, Camera, CameraError, Image};
use eikon_wavefront::LightVolume;
use glam::DVec3;
use rayon::prelude::*;
use std::sync::atomic::{AtomicUsize, Ordering};

/// How eye rays are marched.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Options {
    /// Step length, voxels.
    pub step: f64,
    /// Integrator: Euler [Ihrke07 eqs 11-12] or RK4.
    pub integrator: Integrator,
    /// Cross empty blocks in one straight step.
    pub skip_empty: bool,
    /// Seed of the pixel sample jitter.
    pub seed: u64,
    /// A ray stops once its transmittance has fallen below this in every
    /// channel (what lies behind would add less than this fraction).
    pub min_transmittance: f64,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            step: 0.5,
            integrator: Integrator::Euler,
            skip_empty: true,
            seed: 0,
            min_transmittance: 1e-5,
        }
    }
}

/// The scene's camera, or (without `[camera]`) one looking at the volume
/// from the front and a little above, far enough for the bounds to fill
/// the view.
pub fn camera_settings(scene: &Scene) -> CameraSettings {
    if let Some(c) = &scene.camera {
        return c.clone();
    }
    let g = &scene.grid.geometry;
    let centre = (g.min + g.max) * 0.5;
    let radius = 0.5 * g.diagonal();
    let fov: f64 = 40.0;
    let distance = radius / (0.5 * fov.to_radians()).sin();
    CameraSettings {
        position: centre + DVec3::new(0.0, 0.35, 1.0).normalize() * distance,
        target: centre,
        up: DVec3::Y,
        fov,
        resolution: [800, 600],
        samples: 1,
    }
}

/// The camera that `settings` describe: a scene's `[camera]` or the
/// default of [`camera_settings`], with whatever the caller changed.
///
/// # Errors
///
/// As [`Camera::new`].
pub fn camera(settings: &CameraSettings) -> Result<Camera, CameraError> {
    let c = settings;
    Camera::new(
        c.position,
        c.target,
        c.up,
        c.fov,
        c.resolution[0],
        c.resolution[1],
        c.samples,
    )
}

/// Mirror directions closer than this cosine (a quarter degree) share one
/// lookup of the surroundings.
pub(crate) const MIRROR_COS: f64 = 0.99999;

/// Edge of a square tile of pixels, the unit of parallel work.
pub const TILE: u32 = 16;

/// Counters of one render, for reports and benchmarks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Stats {
    /// Ray steps taken with the ray equation.
    pub steps: u64,
    /// Straight steps across empty blocks.
    pub skips: u64,
}

/// Everything one frame needs.
pub struct Renderer<'a> {
    medium: &'a Medium,
    volumes: &'a [LightVolume],
    surroundings: &'a Surroundings<'a>,
    camera: &'a Camera,
    opts: Options,
    cells: Vec<MacroCells>,
    properties: Properties,
    /// Index at the eye, per channel (the field clamps to its border, so an
    /// eye outside the grid gets the ambient index there).
    eye_index: [f64; 3],
    /// With sharp interfaces: the scene's regions ([`Renderer::sharp`]).
    regions: Option<Regions<'a>>,
    /// With dispersion and sharp interfaces, whether an eye ray starts
    /// carrying all three channels ([`Lanes::All`]): the eye's region is
    /// achromatic.
    shared: bool,
    /// Whether a light volume holds a flux direction per channel, so that
    /// what is looked up in it depends on the channel.
    chromatic_light: bool,
}

// How far either side of a boundary voxel the interface sides are read
// ([`Properties`]): far enough out to clear the band (smoothing plus
// voxelization, about 4.5 voxels either side of the surface); walls
// thinner than this read too small a jump.
pub(crate) use eikon_grid::interface::probe_length;

/// Where a ray is, and what it has gathered.
#[derive(Clone, Copy)]
struct Walk {
    ray: RayState,
    radiance: DVec3,
    alpha: DVec3,
    stats: Stats,
    /// The last mirror direction looked up in the interface band being
    /// crossed, and the radiance seen along it.
    mirrored: Option<(DVec3, DVec3)>,
    /// The ray's direction where it entered the interface band being
    /// crossed.
    incident: Option<DVec3>,
    /// The last step's extinction and length, with what they give
    /// ([`Walk::loss`]).
    loss: Option<(DVec3, f64, Loss)>,
}

/// Over one step of length `l` through a constant extinction `sigma`, per
/// channel: the transmittance `exp(-sigma l)` and the weight of a constant
/// source, `int_0^l exp(-sigma s) ds = (1 - exp(-sigma l)) / sigma`.
#[derive(Clone, Copy)]
struct Loss {
    transmittance: DVec3,
    weight: DVec3,
}

impl Walk {
    /// [`Loss`] of a step, kept for the next: in a homogeneous absorber
    /// step after step has the same extinction and length.
    #[inline]
    fn loss(&mut self, sigma: DVec3, step: f64) -> Loss {
        if let Some((s, l, loss)) = self.loss {
            if s == sigma && l == step {
                return loss;
            }
        }
        let transmittance = (-sigma * step).exp();
        let weight = DVec3::from_array([0, 1, 2].map(|c| {
            if sigma[c] > 1e-12 {
                (1.0 - transmittance[c]) / sigma[c]
            } else {
                step
            }
        }));
        let loss = Loss {
            transmittance,
            weight,
        };
        self.loss = Some((sigma, step, loss));
        loss
    }
}

/// The colour channels one eye ray carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Lanes {
    /// Channel `c` alone, on the path of its own index field.
    One(usize),
    /// All three, along the path they share while no matter on the way
    /// disperses (with sharp interfaces: [`Renderer::trace_sharp`]).
    All,
}

impl Lanes {
    /// The channel whose index the ray follows (under `All` every
    /// channel's index along the path is the same).
    fn index_channel(self) -> usize {
        match self {
            Lanes::One(c) => c,
            Lanes::All => 0,
        }
    }
}

/// How [`Renderer::trace_sharp`] ended. Returned once per ray and never
/// stored, so the larger variant costs a copy, where a box would cost an
/// allocation per parted ray.
#[allow(clippy::large_enum_variant)]
enum Traced {
    /// The radiance gathered and the work done.
    Done(DVec3, Stats),
    /// The channels part at the next step: the ray and walk before it.
    Parted(SharpRay, Walk),
}

impl<'a> Renderer<'a> {
    /// A renderer of `medium` lit by `volumes` (one per light, possibly
    /// none), seen by `camera` against `surroundings`.
    pub fn new(
        medium: &'a Medium,
        volumes: &'a [LightVolume],
        surroundings: &'a Surroundings<'a>,
        camera: &'a Camera,
        opts: Options,
    ) -> Self {
        let cells = if opts.skip_empty {
            (0..medium.channels())
                .map(|c| MacroCells::new(medium, c))
                .collect()
        } else {
            Vec::new()
        };
        Self {
            medium,
            volumes,
            surroundings,
            camera,
            opts,
            cells,
            properties: Properties::new(medium, probe_length(medium)),
            eye_index: [0, 1, 2].map(|c| {
                medium
                    .field(c.min(medium.channels() - 1))
                    .sample(camera.position())
                    .0
            }),
            regions: None,
            shared: false,
            chromatic_light: volumes.iter().any(|v| v.flux.len() > 1),
        }
    }

    /// Render with the exact interfaces of `scene` (`[grid] interfaces =
    /// "sharp"`, [`eikon_grid::region`]): eye rays follow each region's own
    /// index and refract at the exact surfaces, with Fresnel reflection
    /// taken there at the true angle of incidence.
    pub fn sharp(mut self, scene: &'a Scene) -> Self {
        let regions = Regions::new(scene).clear_of(self.medium);
        let eye = self.camera.position();
        let at = regions.at(eye);
        self.shared = self.medium.channels() == 3 && regions.achromatic(at);
        self.eye_index =
            [0, 1, 2].map(|c| regions.index(at, eye, c.min(self.medium.channels() - 1)).0);
        self.regions = Some(regions);
        self
    }

    /// Trace every channel's eye ray on its own from the eye, as without
    /// sharp interfaces: the shared ray of [`Renderer::radiance`] only
    /// saves work, and this is what it is checked against.
    pub fn channels_apart(mut self) -> Self {
        self.shared = false;
        self
    }

    /// Render the frame over tiles in parallel. The result does not depend
    /// on the number of threads: every pixel is computed on its own, its
    /// samples summed in order. `progress` hears `(tiles done, tiles in
    /// all)`.
    pub fn render(&self, progress: Progress) -> (Image, Stats) {
        let (w, h) = (self.camera.width(), self.camera.height());
        let tiles: Vec<(u32, u32)> = (0..h.div_ceil(TILE))
            .flat_map(|ty| (0..w.div_ceil(TILE)).map(move |tx| (tx * TILE, ty * TILE)))
            .collect();
        let done = AtomicUsize::new(0);
        let rendered: Vec<(Vec<[f32; 3]>, Stats)> = tiles
            .par_iter()
            .map(|&(x0, y0)| {
                let mut stats = Stats::default();
                let mut out = Vec::with_capacity((TILE * TILE) as usize);
                for y in y0..(y0 + TILE).min(h) {
                    for x in x0..(x0 + TILE).min(w) {
                        let (l, s) = self.pixel(x, y);
                        stats.steps += s.steps;
                        stats.skips += s.skips;
                        out.push(l.as_vec3().to_array());
                    }
                }
                progress(done.fetch_add(1, Ordering::Relaxed) + 1, tiles.len());
                (out, stats)
            })
            .collect();
        let mut image = Image::new(w, h);
        let mut stats = Stats::default();
        for (&(x0, y0), (pixels, s)) in tiles.iter().zip(rendered) {
            stats.steps += s.steps;
            stats.skips += s.skips;
            let tw = (x0 + TILE).min(w) - x0;
            for (k, p) in pixels.into_iter().enumerate() {
                let (x, y) = (x0 + k as u32 % tw, y0 + k as u32 / tw);
                image.data[(y * w + x) as usize] = p;
            }
        }
        (image, stats)
    }

    /// Mean radiance of pixel `(x, y)` over its samples.
    pub fn pixel(&self, x: u32, y: u32) -> (DVec3, Stats) {
        let n = self.camera.samples();
        let mut sum = DVec3::ZERO;
        let mut stats = Stats::default();
        for s in 0..n {
            let (o, d) = self.camera.ray(x, y, s, self.opts.seed);
            let (l, st) = self.radiance(o, d);
            sum += l;
            stats.steps += st.steps;
            stats.skips += st.skips;
        }
        (sum / n as f64, stats)
    }

    /// Radiance arriving at `o` from the unit direction `-d` (the eye ray
    /// leaves `o` along `d`). With dispersion each channel traces its own
    /// ray through its own index field.
    pub fn radiance(&self, o: DVec3, d: DVec3) -> (DVec3, Stats) {
        if self.medium.channels() == 1 {
            return self.march(o, d, 0);
        }
        // With sharp interfaces the channels share one ray until matter
        // that disperses parts them (each channel's result is the same as
        // from its own ray, with less work where nothing disperses).
        if let Some(regions) = self.regions.as_ref().filter(|_| self.shared) {
            return self.march_sharp(regions, o, d, Lanes::All);
        }
        let mut out = DVec3::ZERO;
        let mut stats = Stats::default();
        for c in 0..3 {
            let (l, s) = self.march(o, d, c);
            out[c] = l[c];
            stats.steps += s.steps;
            stats.skips += s.skips;
        }
        (out, stats)
    }

    /// March one eye ray through index channel `ch`; returns the RGB
    /// radiance it gathers (with dispersion only channel `ch` is used).
    fn march(&self, o: DVec3, d: DVec3, ch: usize) -> (DVec3, Stats) {
        if let Some(regions) = &self.regions {
            return self.march_sharp(regions, o, d, Lanes::One(ch));
        }
        let grid = &self.medium.geometry;
        let env = self.surroundings;
        let Some((t0, _)) = grid.clip_line(o, d).filter(|&(_, t1)| t1 > 0.0) else {
            return (env.radiance(o, d, ch), Stats::default());
        };
        let t0 = t0.max(0.0);
        if let Some(t) = env.receiver_hit(o, d, t0) {
            return (env.receiver_radiance(o + d * t, d, ch), Stats::default());
        }
        let field = self.medium.field(ch);
        let h = grid.voxel_size();
        let ds = self.opts.step * h;
        let x = o + d * t0;
        let mut walk = Walk {
            ray: RayState::new(x, d, field.sample(x).0),
            radiance: DVec3::ZERO,
            alpha: DVec3::ONE,
            stats: Stats::default(),
            mirrored: None,
            incident: None,
            loss: None,
        };
        // A ray caught by total internal reflection may circle for long;
        // after this many volume diagonals it is given up as absorbed.
        let budget = (64.0 * grid.diagonal() / ds) as u64 + 16;
        while walk.stats.steps < budget {
            let dir = walk.ray.v.normalize_or_zero();
            // Distance to the bounds along the ray: the slab test only
            // within two steps of them (farther, a step cannot leave).
            let clearance = (walk.ray.x - grid.min)
                .min(grid.max - walk.ray.x)
                .min_element();
            let exit = if clearance > 2.0 * ds {
                f64::INFINITY
            } else {
                grid.clip_line(walk.ray.x, dir)
                    .map_or(0.0, |(_, t1)| t1.max(0.0))
            };
            if exit <= 0.0 || dir == DVec3::ZERO {
                break;
            }
            if walk.alpha.max_element() < self.opts.min_transmittance {
                return (walk.radiance, walk.stats);
            }
            // A skip may be longer than two steps: it must still end at
            // the bounds, where the surroundings (a board or a plane lying
            // on a face of the grid) take over.
            let skip_exit = || {
                if exit.is_finite() {
                    exit
                } else {
                    grid.clip_line(walk.ray.x, dir)
                        .map_or(0.0, |(_, t1)| t1.max(0.0))
                }
            };
            if let Some(s) = self.cells.get(ch).and_then(|c| c.clear_step(walk.ray.x)) {
                // Clear of anything that bends, scatters, emits or reflects
                // for `s`: one straight step in the local constant medium.
                let t = s.min(skip_exit());
                let n = field.sample(walk.ray.x).0;
                let sigma = self.properties.sample(walk.ray.x).sigma;
                if let Some(tr) = env.receiver_hit(walk.ray.x, dir, t) {
                    let hit = walk.ray.x + dir * tr;
                    walk.alpha *= (-sigma * tr).exp();
                    walk.radiance += walk.alpha * env.receiver_radiance(hit, dir, ch);
                    return (walk.radiance, walk.stats);
                }
                walk.alpha *= (-sigma * t).exp();
                walk.ray.x += dir * t;
                walk.ray.v = dir * n;
                walk.mirrored = None;
                walk.incident = None;
                walk.stats.skips += 1;
                continue;
            }
            if let Some((u, t)) = self.cells.get(ch).and_then(|c| c.crossing(walk.ray.x, dir)) {
                // Just past the block's face, so that the next lookup
                // lands in the next block.
                let t = (t + 1e-6 * h).min(skip_exit());
                if let Some(tr) = env.receiver_hit(walk.ray.x, dir, t) {
                    let hit = walk.ray.x + dir * tr;
                    walk.alpha *= (-u.sigma * tr).exp();
                    walk.radiance += walk.alpha * env.receiver_radiance(hit, dir, ch);
                    return (walk.radiance, walk.stats);
                }
                walk.alpha *= (-u.sigma * t).exp();
                walk.ray.x += dir * t;
                walk.ray.v = dir * u.n;
                walk.mirrored = None;
                walk.incident = None;
                walk.stats.skips += 1;
                continue;
            }
            let step = ds.min(exit.max(1e-6 * h));
            let x0 = walk.ray.x;
            let (n, grad) = field.sample(x0);
            self.gather(x0, (n, grad), dir, step, ch, &mut walk);
            match self.opts.integrator {
                Integrator::Euler => step_euler_sampled(&mut walk.ray, (n, grad), step),
                _ => step_rk4(&field, Form::EqualDistance, &mut walk.ray, step),
            }
            walk.stats.steps += 1;
            let chord = walk.ray.x - x0;
            let len = chord.length();
            if len > 0.0 {
                let u = chord / len;
                if let Some(tr) = env.receiver_hit(x0, u, len) {
                    walk.radiance += walk.alpha * env.receiver_radiance(x0 + u * tr, u, ch);
                    return (walk.radiance, walk.stats);
                }
            }
        }
        if walk.stats.steps >= budget {
            return (walk.radiance, walk.stats);
        }
        let dir = walk.ray.v.normalize_or_zero();
        walk.radiance += walk.alpha * env.radiance(walk.ray.x, dir, ch);
        (walk.radiance, walk.stats)
    }

    /// [`Renderer::march`] with sharp interfaces: region by region, each
    /// region's own material, straight from surface to surface where the
    /// index is constant and nothing along the way scatters or emits, Fresnel
    /// at every true crossing ([Ihrke07 eq 2]'s reflection term and
    /// [Ihrke07 eq 5]'s `tau`, at the exact angle of incidence).
    ///
    /// With [`Lanes::All`] one ray carries the three colour channels while
    /// its path is theirs alike, and splits into one ray per channel where
    /// they part (see [`Renderer::trace_sharp`]).
    fn march_sharp(&self, regions: &Regions, o: DVec3, d: DVec3, lanes: Lanes) -> (DVec3, Stats) {
        let grid = &self.medium.geometry;
        let env = self.surroundings;
        let Some((t0, _)) = grid.clip_line(o, d).filter(|&(_, t1)| t1 > 0.0) else {
            return (
                self.per_channel(lanes, |c| env.radiance(o, d, c)),
                Stats::default(),
            );
        };
        let t0 = t0.max(0.0);
        if let Some(t) = env.receiver_hit(o, d, t0) {
            let l = self.per_channel(lanes, |c| env.receiver_radiance(o + d * t, d, c));
            return (l, Stats::default());
        }
        let ray = regions.ray(o + d * t0, d, lanes.index_channel());
        let walk = Walk {
            ray: ray.s,
            radiance: DVec3::ZERO,
            alpha: DVec3::ONE,
            stats: Stats::default(),
            mirrored: None,
            incident: None,
            loss: None,
        };
        self.finish_sharp(regions, ray, walk, lanes)
    }

    /// Go on with `ray` from `walk` to the end; a ray carrying every channel
    /// that comes to dispersing matter goes on from there as three rays,
    /// each giving its own channel.
    fn finish_sharp(
        &self,
        regions: &Regions,
        ray: SharpRay,
        walk: Walk,
        lanes: Lanes,
    ) -> (DVec3, Stats) {
        match self.trace_sharp(regions, ray, walk, lanes) {
            Traced::Done(l, stats) => (l, stats),
            Traced::Parted(ray, walk) => {
                let mut out = DVec3::ZERO;
                let mut stats = walk.stats;
                for c in 0..3 {
                    let (l, s) = self.finish_sharp(regions, ray, walk, Lanes::One(c));
                    out[c] = l[c];
                    stats.steps += s.steps - walk.stats.steps;
                    stats.skips += s.skips - walk.stats.skips;
                }
                (out, stats)
            }
        }
    }

    /// The step loop of [`Renderer::march_sharp`]. Under [`Lanes::All`] the
    /// path is followed with channel 0's index, which is every channel's
    /// while the ray stays in achromatic regions ([`Regions::achromatic`]);
    /// what the light volumes and the surroundings give is looked up per
    /// channel. Before a step that would take the ray into a region whose
    /// index differs by channel (or meet such a surface and reflect), it
    /// stops and hands back its state before that step: each channel then
    /// takes that step itself, so every channel's result is exactly the
    /// one its own ray gives.
    fn trace_sharp(
        &self,
        regions: &Regions,
        mut ray: SharpRay,
        mut walk: Walk,
        lanes: Lanes,
    ) -> Traced {
        let grid = &self.medium.geometry;
        let env = self.surroundings;
        let ch = lanes.index_channel();
        let all = lanes == Lanes::All;
        if all && !regions.achromatic(ray.region) {
            return Traced::Parted(ray, walk);
        }
        let (ds, budget) = self.sharp_steps();
        let lit = !self.volumes.is_empty();
        // Along a straight piece (a uniform region, no surface met) the
        // grid's exit is clipped once: where it lies farther than two steps
        // the step is `ds` whatever its exact distance.
        let mut piece: Option<(DVec3, f64)> = None;
        while walk.stats.steps + walk.stats.skips < budget {
            let dir = ray.s.v.normalize_or_zero();
            if dir == DVec3::ZERO {
                break;
            }
            if walk.alpha.max_element() < self.opts.min_transmittance {
                return Traced::Done(walk.radiance, walk.stats);
            }
            let before = (ray, walk);
            let x0 = ray.s.x;
            let m = regions.material(ray.region);
            let sigma = m.extinction_at(x0);
            let here = Sample {
                sigma,
                delta: 0.0,
                scatter: m.albedo * sigma,
                g: m.g,
                emission: m.emission,
            };
            // Long straight steps where nothing needs gathering on the way:
            // a constant index with no scattering (or no light) and no
            // emission, and an extinction that is one constant.
            let straight = regions.uniform(ray.region);
            let quiet = straight
                && (here.scatter == DVec3::ZERO || !lit)
                && here.emission == DVec3::ZERO
                && m.extinction_grid.is_none();
            let far = !quiet && piece.is_some_and(|(x, exit)| exit - (x0 - x).length() > 2.0 * ds);
            let exit = if far {
                f64::INFINITY
            } else {
                let exit = grid.clip_line(x0, dir).map_or(0.0, |(_, t1)| t1.max(0.0));
                piece = straight.then_some((x0, exit));
                exit
            };
            if exit <= 0.0 {
                break;
            }
            let n = regions.index(ray.region, x0, ch).0;
            if far && straight && m.extinction_grid.is_none() {
                let (origin, edge) = piece.expect("a far edge is a straight piece's");
                if self.gather_straight(
                    regions,
                    &mut ray,
                    &mut walk,
                    (origin, edge),
                    (&here, n),
                    lanes,
                ) {
                    continue;
                }
            }
            let step = if quiet { exit } else { ds.min(exit) };
            let st = regions.step(
                &mut ray,
                Form::EqualDistance,
                self.opts.integrator,
                step,
                ch,
            );
            if all
                && (!regions.achromatic(ray.region)
                    || st.event.is_some_and(|e| !regions.achromatic(e.to)))
            {
                return Traced::Parted(before.0, before.1);
            }
            if quiet {
                walk.stats.skips += 1;
            } else {
                walk.stats.steps += 1;
            }
            let chord = ray.s.x - x0;
            let len = chord.length();
            if len > 0.0 {
                let u = chord / len;
                if let Some(tr) = env.receiver_hit(x0, u, len) {
                    let tri = grid.trilinear(x0);
                    self.absorb_and_emit(&tri, &here, n, u, tr, lanes, &mut walk);
                    let hit = x0 + u * tr;
                    walk.radiance +=
                        walk.alpha * self.per_channel(lanes, |c| env.receiver_radiance(hit, u, c));
                    return Traced::Done(walk.radiance, walk.stats);
                }
            }
            let tri = grid.trilinear(x0);
            self.absorb_and_emit(&tri, &here, n, dir, st.used, lanes, &mut walk);
            if st.at_surface || st.event.is_some() {
                piece = None;
            }
            if let Some(ev) = st.event.filter(|e| !e.total) {
                let rho = ev.reflectance;
                if rho > 0.0 {
                    let mirror = fresnel::reflect(ev.incident, ev.normal);
                    let l = self.per_channel(lanes, |c| env.radiance(ev.point, mirror, c));
                    walk.radiance += walk.alpha * l * rho;
                    walk.alpha *= 1.0 - rho;
                }
            }
            if !st.at_surface && step >= exit {
                break;
            }
            if !grid.contains(ray.s.x) {
                break;
            }
        }
        if walk.stats.steps + walk.stats.skips >= budget {
            return Traced::Done(walk.radiance, walk.stats);
        }
        let dir = ray.s.v.normalize_or_zero();
        let x = ray.s.x;
        walk.radiance += walk.alpha * self.per_channel(lanes, |c| env.radiance(x, dir, c));
        Traced::Done(walk.radiance, walk.stats)
    }

    /// The steps [`Self::trace_sharp`] takes along a straight piece (from
    /// `origin`, the grid's edge `edge` on) through a uniform region that
    /// gathers light, while nothing but where the light volumes are read
    /// changes from one to the next: no surface within the ray's look
    /// ahead, the grid's edge and the receiver beyond the step, the ray
    /// still bright. Each is the general step's gather over `ds`, then the
    /// move. `false` where not one step was taken (the general step goes
    /// on).
    fn gather_straight(
        &self,
        regions: &Regions,
        ray: &mut SharpRay,
        walk: &mut Walk,
        (origin, edge): (DVec3, f64),
        (here, n): (&Sample, f64),
        lanes: Lanes,
    ) -> bool {
        let grid = &self.medium.geometry;
        let (ds, budget) = self.sharp_steps();
        // What the general step asks to pass no surface ([`Regions::step`]).
        let reach = ds + 2.0 * regions.eps();
        let dir = ray.s.v.normalize_or_zero();
        // Along the line: the grid's edge and the receiver, once. Within two
        // steps of either the general step takes over (it finds the exact
        // end).
        let x = ray.s.x;
        let mut left = (edge - (x - origin).length()).min(
            self.surroundings
                .receiver_hit(x, dir, f64::INFINITY)
                .unwrap_or(f64::INFINITY),
        );
        let mut taken = false;
        while let Some(free) = ray.ahead {
            if reach > free
                || left <= 2.0 * ds
                || walk.stats.steps + walk.stats.skips >= budget
                || walk.alpha.max_element() < self.opts.min_transmittance
            {
                break;
            }
            let x0 = ray.s.x;
            let tri = grid.trilinear(x0);
            self.absorb_and_emit(&tri, here, n, dir, ds, lanes, walk);
            ray.s.x = x0 + dir * ds;
            ray.s.v = dir * n;
            ray.s.opl += n * ds;
            ray.ahead = Some(free - ds);
            left -= ds;
            walk.stats.steps += 1;
            taken = true;
        }
        taken
    }

    /// [`Self::trace_sharp`]'s step, world units, and the most steps and
    /// skips a ray takes.
    fn sharp_steps(&self) -> (f64, u64) {
        let grid = &self.medium.geometry;
        let ds = self.opts.step * grid.voxel_size();
        (ds, (64.0 * grid.diagonal() / ds) as u64 + 16)
    }

    /// `f` for the ray's channels: `f(c)` for one channel `c`; for all
    /// three, channel `c` of `f(c)` for each (one call where the light
    /// volumes hold one flux direction for every channel, so that nothing
    /// `f` looks up depends on the channel).
    #[inline]
    fn per_channel(&self, lanes: Lanes, f: impl Fn(usize) -> DVec3) -> DVec3 {
        match lanes {
            Lanes::One(c) => f(c),
            Lanes::All if !self.chromatic_light => f(0),
            Lanes::All => DVec3::new(f(0).x, f(1).y, f(2).z),
        }
    }

    /// The medium's part of [Ihrke07 eq 1] over one step of length `step`
    /// along the unit `d`, the medium taken as `here` (index `n`) over the
    /// step: in-scatter from every light volume, emission, attenuation.
    #[allow(clippy::too_many_arguments)]
    fn absorb_and_emit(
        &self,
        tri: &eikon_grid::Trilinear,
        here: &Sample,
        n: f64,
        d: DVec3,
        step: f64,
        lanes: Lanes,
        w: &mut Walk,
    ) {
        let sigma = here.sigma;
        let mut source = here.emission;
        if here.scatter.max_element() > 0.0 {
            for v in self.volumes {
                // One fluence read for every channel; each its own flux.
                let Some(fluence) = LightSample::fluence(v, tri) else {
                    continue;
                };
                if here.g == 0.0 {
                    // Isotropic: the phase function is `1 / (4 pi)` (HG at
                    // g = 0) whatever the light's direction, which need
                    // not be read.
                    source += here.scatter * fluence * hg(1.0, 0.0);
                    continue;
                }
                source += self.per_channel(lanes, |ch| {
                    let light = LightSample::with_fluence(v, tri, fluence, ch);
                    // [Ihrke07 eq 6] with the first angular moment of the
                    // light: HG about the net flux direction with g scaled
                    // by the mean cosine (exact for one ray family, mu =
                    // 1), between the light's direction of travel and the
                    // direction towards the eye.
                    here.scatter
                        * light.fluence
                        * hg(light.direction.dot(-d), here.g * light.mean_cosine)
                });
            }
        }
        // The radiance law: L / n^2 is what a ray carries unchanged
        // ([Ihrke07 eq 1] leaves it out), so radiance arising where the index
        // is n reaches an eye in index n_eye scaled by (n_eye / n)^2.
        // Without it matter in glass would look n^2 too bright. (Under
        // `Lanes::All` the eye's region is achromatic: one eye index.)
        source *= (self.eye_index[lanes.index_channel()] / n).powi(2);
        // Exact for constant sigma and S over the step:
        // int_0^ds exp(-sigma s) ds = (1 - exp(-sigma ds)) / sigma.
        if sigma.max_element() > 0.0 {
            let loss = w.loss(sigma, step);
            if source != DVec3::ZERO {
                w.radiance += w.alpha * source * loss.weight;
            }
            w.alpha *= loss.transmittance;
        } else if source != DVec3::ZERO {
            w.radiance += w.alpha * source * step;
        }
    }

    /// [Ihrke07 eq 1] over one step of length `step` from `x` along the unit
    /// `d`: in-scatter, emission, attenuation and Fresnel at boundaries (see
    /// the module docs).
    #[allow(clippy::too_many_arguments)]
    fn gather(
        &self,
        x: DVec3,
        (n, grad): (f64, DVec3),
        d: DVec3,
        step: f64,
        ch: usize,
        w: &mut Walk,
    ) {
        let tri = self.medium.geometry.trilinear(x);
        let here = self.properties.sample_at(&tri);
        self.absorb_and_emit(&tri, &here, n, d, step, Lanes::One(ch), w);

        let delta = here.delta;
        if delta <= 0.0 {
            w.mirrored = None;
            w.incident = None;
            return;
        }
        let len = grad.length();
        if len == 0.0 {
            return;
        }
        let normal = grad / len;
        let cos = d.dot(normal);
        let part = (delta * step * cos.abs()).min(1.0);
        // n increases along `normal`; the two sides were read beyond the
        // smoothed interface (`Properties`).
        let sides = self.properties.sides_at(&tri, ch);
        // Within the band the ray is already partly refracted; Fresnel
        // wants the angle it met the interface at, in the medium it came
        // from: its direction where it entered the band (the smoothing's
        // tail bends nothing), kept until it leaves the band.
        let incident = *w.incident.get_or_insert(d);
        let cos_in = incident.dot(normal);
        let tangent = incident - normal * cos_in;
        let sin_i = tangent.length().min(1.0);
        let cos_i = cos_in.abs();
        let (n1, n2) = if cos_in > 0.0 {
            (sides.lo, sides.hi)
        } else {
            (sides.hi, sides.lo)
        };
        if n1 / n2 * sin_i < 1.0 {
            let rho = fresnel::reflectance(cos_i, n1, n2);
            if rho > 0.0 {
                // The incident direction's mirror image. What it sees is
                // looked up again only when it has turned (across one band
                // it hardly does).
                let mirror = fresnel::reflect(incident, normal);
                let l_r = match w.mirrored {
                    Some((m, l)) if m.dot(mirror) > MIRROR_COS => l,
                    _ => {
                        let l = self.surroundings.radiance(x, mirror, ch);
                        w.mirrored = Some((mirror, l));
                        l
                    }
                };
                w.radiance += w.alpha * l_r * (part * rho);
                w.alpha *= (1.0 - rho).powf(part);
            }
        }
    }
}
