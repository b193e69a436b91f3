//! The brute-force photon baseline: the same light, medium and ray
//! equation as the wavefront, traced one particle at a time with no
//! intensity law, so the two can check each other.
//!
//! # Emission
//! Photons follow the distribution of the wavefront that [`light::emit`]
//! tiles, sampled at random instead of on a lattice:
//! * directional: uniform points on the rectangle of the box's projection
//!   that the plane wave is tiled over, each carrying
//!   `irradiance * rectangle area / count`;
//! * point: uniform directions on the sphere, each carrying `power / count`;
//! * spot: the same, times the spot's cone weight.
//!
//! The draws are stratified (jittered): the emission domain, the plane's
//! rectangle or the sphere in the equal-area coordinates `(z, phi)`, is cut
//! into `count` cells of equal area, in rows, and photon `i` is uniform in
//! cell `i`. Each photon is still uniform over its cell and the cells tile
//! the domain, so the estimate stays unbiased; its variance is never above
//! that of independent draws and, in a beam, much lower (every voxel column
//! gets its share of photons, not a Poisson number). Consecutive photons
//! also start side by side, so their paths share the cache lines of the
//! voxel fields.
//!
//! A photon whose line misses the box carries no light into it: it is
//! dropped and not counted as entered. The others start like a patch
//! corner, half a voxel before their ray enters the bounds (on the
//! one-voxel sphere for a point light inside the volume), with
//! `v = n * direction`.
//!
//! # Transport
//! Exactly as [`propagate`](crate::propagate::propagate) moves a patch
//! corner: the equal-time ray equation [Ihrke07 eqs 14-15] with the same
//! integrator and step in the [`Bounded`] field, on the eikonal shell
//! `|v| = n`, straight through empty space ([`EmptySpace`]), and
//! [Ihrke07 eq 18]'s attenuation by the trapezoid of `sigma_t / n` before and
//! after each step times `dt`. Where a photon goes straight through a
//! constant index that does not absorb (empty blocks of the smoothed
//! field; with sharp interfaces a uniform clear region, up to the first
//! surface on its way) it takes as many steps as one chord, its clock
//! still on whole steps: the same path, the same deposit but for rounding,
//! at a fraction of the cost. A photon ends when
//! it has left the bounds (it is outside and its forward line misses the
//! box), when its transmittance is below the threshold in every channel,
//! or at the wavefront's step limit.
//!
//! # Estimator
//! The track-length estimator of the fluence rate and the net flux
//! ([`deposit`](crate::deposit)): a photon of flux `P` that travels a
//! length `l` through a cell of volume `V` adds `P l / V` to its fluence
//! and that times its direction to its flux vector, exactly as a
//! wavefront chord does, so the two estimate the same
//! [`LightVolume`]. Fresnel transmission at interfaces is applied per step
//! as for a patch ([`Interfaces::transmittance`]), the reflected part
//! counted as reflected; with sharp interfaces and [`Options::reflections`]
//! the reflected part goes on as a branch of the photon, the mirror image of its ray at the surface
//! (as the wavefront's reflected patches do), traced after it.
//!
//! Each step's chord is split exactly among the cells it crosses (a 3D DDA)
//! and each piece carries the flux integrated over it, with the step's
//! optical depth spread evenly along the step. Binning a whole step into the
//! cell of its midpoint would alias: every photon of a plane wave entering
//! through one face starts at the same depth, so all their step midpoints
//! share one phase against the cells and whole slabs get too many or too
//! few. Measured with 300k photons of a plane wave along (0.2, -1, 0.1) in
//! vacuum: slabs 2% low, and a mean per-voxel error of 5.0% instead of the
//! 2.0% of the noise alone; more photons do not remove it.
//!
//! # Determinism
//! Photon `i` draws from its own SplitMix64 stream keyed by `(seed, i)`,
//! so it does not matter which thread traces it. Deposits are fixed-point
//! integers added atomically, which commutes; energy sums are taken per
//! fixed chunk of photons and added in chunk order. The volume and the
//! summary are therefore bitwise the same for any thread count.

use crate::deposit::Counters;
use crate::light::{self, PlaneFrame};
use crate::propagate::{region_extinction_per_index, step_depth, Bounded, RegionIndex};
use crate::{Error, LightVolume, Options, Summary};
use eikon_grid::interface::{probe_length, Interfaces};
use eikon_grid::ray::{step_euler_on_shell, step_rk4_on_shell};
use eikon_grid::region::{Regions, SharpRay};
use eikon_grid::{EmptySpace, Form, GridGeometry, IndexField, Integrator, Light, Medium, RayState};
use eikon_optics::spot::cone_weight;
use eikon_rng::{mix, SplitMix64, GOLDEN};
use glam::DVec3;
use rayon::prelude::*;
use std::f64::consts::PI;

/// Fixed-point units that the brightest photon deposits by crossing one
/// voxel edge-on (a path of one voxel length). Rounding each deposit to a
/// unit then costs at most 2^-25 of such a deposit, and a 64-bit counter
/// holds 2^39 (about 5 10^11) such crossings per cell before it could
/// overflow; fewer units where the photons and steps could cross one cell
/// more often than that ([`crate::units_per_crossing`]).
const UNITS_PER_CROSSING: f64 = (1u64 << 24) as f64;

/// Photons per work item: the energy sums are taken per chunk and then
/// added in chunk order, so they do not depend on the thread count.
const CHUNK: usize = 1024;

/// Chunks traced between two reductions of their tallies.
const BATCH: usize = 4096;

/// Bytes the photon tracer holds besides the light volume and its
/// counters, on a grid of `cells` voxels: the clear-cell mask and one
/// batch of chunk tallies (the interface sides are counted apart).
pub fn working_bytes(cells: u128) -> u128 {
    cells * std::mem::size_of::<bool>() as u128 + (BATCH * std::mem::size_of::<Tally>()) as u128
}

/// Trace `count` photons of `light` through `medium` (one set per colour
/// channel with dispersion, each through its own index field, from the
/// same draws) and estimate the fluence rate and the net flux per cell, the
/// same [`LightVolume`] the wavefront writes. `seed` picks the random numbers: the same
/// seed gives bitwise the same result whatever the number of threads.
///
/// Of `opts`, `step`, `integrator`, `threshold`, `max_steps` and `fresnel` apply, with
/// the same meaning as for the wavefront. In the summary, `emitted` counts
/// photons that entered the volume, `exited`, `absorbed` (below the
/// threshold) and `step_limit` how they ended, `steps` is the longest
/// photon's, and the patch counts (`peak_patches`, `caustic`, `held`) are
/// zero. The powers are accounted as for the wavefront: culled power is
/// what photons carried when the threshold ended them, trapped power what
/// they carried at the step limit.
pub fn simulate_photons(
    light: &Light,
    medium: &Medium,
    count: usize,
    seed: u64,
    opts: &Options,
) -> Result<(LightVolume, Summary), Error> {
    simulate_photons_in(light, medium, None, count, seed, opts)
}

/// [`simulate_photons`] with sharp interfaces when `regions` are given: each
/// photon crosses the scene's exact surfaces (Snell's law or total
/// internal reflection, Fresnel transmission on its flux), each region's own
/// index between them, its chords deposited piece by piece.
pub fn simulate_photons_in(
    light: &Light,
    medium: &Medium,
    regions: Option<&Regions>,
    count: usize,
    seed: u64,
    opts: &Options,
) -> Result<(LightVolume, Summary), Error> {
    trace_photons(light, medium, regions, count, seed, opts, true)
}

/// [`simulate_photons_in`]; with `runs` false every photon takes its
/// steps one by one (the runs' own check: they change nothing but
/// rounding).
fn trace_photons(
    light: &Light,
    medium: &Medium,
    regions: Option<&Regions>,
    count: usize,
    seed: u64,
    opts: &Options,
    runs: bool,
) -> Result<(LightVolume, Summary), Error> {
    opts.check()?;
    if count == 0 {
        return Err(Error::Option {
            option: "photons",
            message: "need at least one photon".into(),
        });
    }
    if !medium.has_voxel_fields() {
        return Err(Error::NeedsVoxelFields("the photon tracer"));
    }
    let grid = &medium.geometry;
    let h = grid.voxel_size();
    let dt = opts.step * h;
    let n_max = medium.index_range().1 as f64;
    let max_steps = opts
        .max_steps
        .unwrap_or((16.0 * grid.diagonal() * n_max / dt).ceil() as usize);
    let clear = clear_cells(medium);
    let groups = medium.channels();
    let key = mix(seed.wrapping_add(GOLDEN));
    let mut summary = Summary::default();
    // Fixed-point scale: the largest photon flux of any channel over one
    // voxel length gives UNITS_PER_CROSSING, or fewer where all the
    // photons over all the steps could overflow a counter.
    let white = Source::new(light, grid, count, [1.0; 3]);
    let top = white.flux.iter().copied().fold(0.0, f64::max);
    let crossings = count as f64 * crate::crossings_bound(medium, opts.step, max_steps);
    let units = UNITS_PER_CROSSING.min(crate::units_per_crossing(crossings));
    let tally = Counters::new(grid, groups, [top; 3], units);
    let interfaces =
        (opts.fresnel && regions.is_none()).then(|| Interfaces::new(medium, probe_length(medium)));
    for g in 0..groups {
        let (mask, group) = crate::group(g, groups);
        let source = Source::new(light, grid, count, mask);
        let strata = Strata::new(count, source.aspect());
        let tracer = Tracer {
            medium,
            grid,
            field: Bounded::new(medium, g),
            empty: EmptySpace::new(medium, g),
            integrator: opts.integrator,
            dt,
            threshold: opts.threshold,
            max_steps,
            runs,
            clear: &clear,
            tally: &tally,
            group,
            interfaces: interfaces.as_ref(),
            channel: g,
            sharp: regions.map(|r| {
                let fresnel = match (opts.fresnel, opts.reflections) {
                    (false, _) => Fresnel::Off,
                    (true, false) => Fresnel::Dropped,
                    (true, true) => Fresnel::Traced,
                };
                (r, fresnel)
            }),
        };
        // Chunks run in batches so that the per-chunk tallies held at once
        // stay bounded whatever the count; they are added in chunk order,
        // so the sums do not depend on the thread count.
        let chunks = count.div_ceil(CHUNK);
        for batch in (0..chunks).step_by(BATCH) {
            let tallies: Vec<Tally> = (batch..(batch + BATCH).min(chunks))
                .into_par_iter()
                .map(|chunk| {
                    let mut t = Tally::default();
                    for i in chunk * CHUNK..((chunk + 1) * CHUNK).min(count) {
                        let mut rng = stream(key, i as u64);
                        let (a, b) = strata.draw(i, &mut rng);
                        let launched = match regions {
                            Some(r) => source.launch(
                                a,
                                b,
                                grid,
                                &RegionIndex {
                                    regions: r,
                                    channel: g,
                                },
                            ),
                            None => source.launch(a, b, grid, &tracer.field),
                        };
                        if let Some((s, flux)) = launched {
                            tracer.trace(s, flux, &mut t);
                        }
                    }
                    t
                })
                .collect();
            for t in &tallies {
                t.add_to(&mut summary);
            }
        }
    }
    let volume = tally.into_volume();
    crate::check_finite(&volume, &summary)?;
    Ok((volume, summary))
}

// ---------------------------------------------------------------------------
// Random numbers.

/// The SplitMix64 stream of one photon. The start state hashes the run's
/// key (itself a hash of the seed) with the photon's index, so photons of
/// one seed, and the photon sets of two seeds, do not share streams.
fn stream(key: u64, index: u64) -> SplitMix64 {
    SplitMix64::new(mix(key ^ index))
}

// ---------------------------------------------------------------------------
// Emission.

/// An equal-area partition of the unit square into `count` cells: `rows`
/// rows, row `r` holding photons `start(r)..start(r + 1)` in cells of equal
/// width, its height proportional to that number.
struct Strata {
    count: u128,
    rows: u128,
}

impl Strata {
    /// Cells about square for a domain `aspect` times wider than high.
    fn new(count: usize, aspect: f64) -> Self {
        let rows = (count as f64 / aspect)
            .sqrt()
            .round()
            .clamp(1.0, count as f64);
        Self {
            count: count as u128,
            rows: rows as u128,
        }
    }

    /// First photon of row `r`.
    fn start(&self, r: u128) -> u128 {
        r * self.count / self.rows
    }

    /// Photon `i`'s point: uniform in its cell of the unit square.
    fn draw(&self, i: usize, rng: &mut SplitMix64) -> (f64, f64) {
        let i = i as u128;
        // Row of photon i: start(r) <= i < start(r + 1).
        let mut r = (i * self.rows / self.count).min(self.rows - 1);
        while r > 0 && self.start(r) > i {
            r -= 1;
        }
        while r + 1 < self.rows && self.start(r + 1) <= i {
            r += 1;
        }
        let (lo, hi) = (self.start(r), self.start(r + 1));
        let width = (hi - lo) as f64;
        let a = ((i - lo) as f64 + rng.unit()) / width;
        let b = (lo as f64 + rng.unit() * width) / self.count as f64;
        (a.min(1.0), b.min(1.0))
    }
}

enum Shape {
    /// The plane wave's rectangle: `u a + w b + d s0` for `a` in `[a0, a1]`
    /// and `b` in `[b0, b1]`, as in `light::emit`.
    Plane {
        d: DVec3,
        u: DVec3,
        w: DVec3,
        a: (f64, f64),
        b: (f64, f64),
        s0: f64,
    },
    /// Directions from a point, with an optional spot cone.
    Sphere {
        p: DVec3,
        cone: Option<(DVec3, f64, f64)>,
    },
}

/// Where photons come from and what each carries.
struct Source {
    shape: Shape,
    /// RGB flux of a photon of full (spot) weight, W: the most any photon
    /// carries, which sets the fixed-point scale.
    flux: [f64; 3],
}

impl Source {
    fn new(light: &Light, grid: &GridGeometry, count: usize, mask: [f64; 3]) -> Source {
        let share =
            |power: DVec3, area: f64| [0, 1, 2].map(|c| power[c] * mask[c] * area / count as f64);
        let (shape, flux) = match light {
            Light::Directional { direction, power } => {
                let d = *direction;
                let PlaneFrame { u, w, a, b, s0 } = PlaneFrame::new(d, grid);
                let area = (a.1 - a.0) * (b.1 - b.0);
                (Shape::Plane { d, u, w, a, b, s0 }, share(*power, area))
            }
            Light::Point { position, power } => (
                Shape::Sphere {
                    p: *position,
                    cone: None,
                },
                share(*power, 1.0),
            ),
            Light::Spot {
                position,
                direction,
                angle,
                falloff,
                power,
            } => (
                Shape::Sphere {
                    p: *position,
                    cone: Some((*direction, *angle, *falloff)),
                },
                share(*power, 1.0),
            ),
        };
        Source { shape, flux }
    }

    /// Width over height of the emission domain in the coordinates
    /// [`Self::launch`] takes.
    fn aspect(&self) -> f64 {
        match self.shape {
            Shape::Plane { a, b, .. } if b.1 > b.0 => ((a.1 - a.0) / (b.1 - b.0)).max(1e-6),
            // (z, phi) spans 2 by 2 pi.
            _ => 1.0 / PI,
        }
    }

    /// The photon at `(sa, sb)` of the unit square (uniform there): its
    /// start state and flux, or `None` when its ray misses the volume (or a
    /// spot's cone).
    fn launch<F: IndexField + ?Sized>(
        &self,
        sa: f64,
        sb: f64,
        grid: &GridGeometry,
        field: &F,
    ) -> Option<(RayState, [f64; 3])> {
        let h = grid.voxel_size();
        let margin = light::MARGIN_VOXELS * h;
        let (x, dir, weight) = match self.shape {
            Shape::Plane { d, u, w, a, b, s0 } => {
                let aa = a.0 + sa * (a.1 - a.0);
                let bb = b.0 + sb * (b.1 - b.0);
                let on_plane = u * aa + w * bb + d * s0;
                let (t0, t1) = grid.clip_line(on_plane, d)?;
                if t1 <= 0.0 {
                    return None;
                }
                (on_plane + d * (t0 - margin).max(0.0), d, 1.0)
            }
            Shape::Sphere { p, cone } => {
                // Uniform on the sphere: z uniform in [-1, 1] (Archimedes).
                let z = 1.0 - 2.0 * sa;
                let phi = 2.0 * PI * sb;
                let r = (1.0 - z * z).max(0.0).sqrt();
                let dir = DVec3::new(r * phi.cos(), r * phi.sin(), z);
                let weight = cone_weight(dir, cone);
                if weight == 0.0 {
                    return None;
                }
                // A photon, unlike a patch, needs no area: one from a light
                // inside the volume starts at the light itself, and is
                // attenuated (and deposits) from there on.
                let start = if grid.contains(p) {
                    0.0
                } else {
                    match grid.clip_line(p, dir) {
                        Some((t0, t1)) if t1 > 0.0 => {
                            (t0 - margin).max(light::INNER_RADIUS_VOXELS * h)
                        }
                        _ => return None,
                    }
                };
                (p + dir * start, dir, weight)
            }
        };
        let flux = self.flux.map(|f| f * weight);
        Some((RayState::new(x, dir, field.sample(x).0), flux))
    }
}

// ---------------------------------------------------------------------------
// Transport.

/// Energy book-keeping of a chunk of photons.
#[derive(Default)]
struct Tally {
    entered: [f64; 3],
    absorbed: [f64; 3],
    exited: [f64; 3],
    reflected: [f64; 3],
    culled: [f64; 3],
    trapped: [f64; 3],
    photons: usize,
    exits: usize,
    thresholded: usize,
    step_limit: usize,
    steps: usize,
    /// Reflected photons still to trace (a photon's branches; reused).
    branches: Vec<(SharpRay, [f64; 3])>,
    /// Reflected photons traced.
    reflections: usize,
}

impl Tally {
    fn add_to(&self, s: &mut Summary) {
        for c in 0..3 {
            s.entered[c] += self.entered[c];
            s.absorbed_power[c] += self.absorbed[c];
            s.exited_power[c] += self.exited[c];
            s.reflected_power[c] += self.reflected[c];
            s.culled_power[c] += self.culled[c];
            s.trapped_power[c] += self.trapped[c];
        }
        s.emitted += self.photons;
        s.exited += self.exits;
        s.absorbed += self.thresholded;
        s.step_limit += self.step_limit;
        s.steps = s.steps.max(self.steps);
        s.reflections += self.reflections;
    }
}

fn add(acc: &mut [f64; 3], x: &[f64; 3]) {
    (0..3).for_each(|c| acc[c] += x[c]);
}

struct Tracer<'a> {
    medium: &'a Medium,
    grid: &'a GridGeometry,
    field: Bounded<'a>,
    empty: EmptySpace,
    integrator: Integrator,
    dt: f64,
    threshold: f64,
    max_steps: usize,
    /// Take straight steps through constant space as one ([`Self::run`]).
    runs: bool,
    clear: &'a [bool],
    tally: &'a Counters,
    /// The colour channel traced, with dispersion.
    group: Option<usize>,
    /// Interface sides for Fresnel transmission, when applied.
    interfaces: Option<&'a Interfaces>,
    /// Index channel traced.
    channel: usize,
    /// Sharp interfaces: the scene's regions, and how Fresnel applies.
    sharp: Option<(&'a Regions<'a>, Fresnel)>,
}

/// What a sharp interface does with the Fresnel-reflected part.
#[derive(Clone, Copy, PartialEq)]
enum Fresnel {
    /// Nothing is reflected (the paper's [Ihrke07 eq 18]).
    Off,
    /// The reflected part leaves the beam, counted as reflected.
    Dropped,
    /// The reflected part goes on as a photon of its own (a branch).
    Traced,
}

/// Per interpolation cell (the lower corner `i0` that
/// [`Medium::sample_rgb`] interpolates from), whether all eight samples
/// it reads have zero extinction: there the sample is exactly zero, and
/// most of a scene's volume is usually clear air.
fn clear_cells(medium: &Medium) -> Vec<bool> {
    let [nx, ny, nz] = medium.geometry.dims;
    let ext = &medium.extinction;
    let mut out = vec![false; nx * ny * nz];
    for i in 0..nx {
        for j in 0..ny {
            for k in 0..nz {
                out[(i * ny + j) * nz + k] = (0..8).all(|corner| {
                    let (a, b, c) = (
                        (i + (corner & 1)).min(nx - 1),
                        (j + ((corner >> 1) & 1)).min(ny - 1),
                        (k + ((corner >> 2) & 1)).min(nz - 1),
                    );
                    (0..3).all(|ch| ext[[a, b, c, ch]] == 0.0)
                });
            }
        }
    }
    out
}

impl Tracer<'_> {
    /// `sigma_t / n` per channel at `p`, zero outside the bounds: the
    /// integrand of [Ihrke07 eq 18] exactly as `propagate` samples it (bitwise:
    /// in a clear cell `sample_rgb` adds up exact zeros).
    #[inline]
    fn extinction_per_index(&self, p: DVec3) -> DVec3 {
        if !self.grid.contains(p) || self.empty.index_at(p).is_some() {
            return DVec3::ZERO;
        }
        // The interpolation cell exactly as `Medium::sample_rgb` finds it.
        let g = self.grid;
        let hi = DVec3::new(g.dims[0] as f64, g.dims[1] as f64, g.dims[2] as f64) - 1.0;
        let u = g.world_to_voxel(p).clamp(DVec3::ZERO, hi);
        let [i, j, k] = [0, 1, 2].map(|a| (u[a] as usize).min(g.dims[a].saturating_sub(2)));
        if self.clear[(i * g.dims[1] + j) * g.dims[2] + k] {
            return DVec3::ZERO;
        }
        self.medium.sample_rgb(&self.medium.extinction, p) / self.field.sample(p).0
    }

    /// One step of `dt` optical path with sharp interfaces: piece by piece,
    /// surface to surface, each piece deposited and attenuated
    /// [Ihrke07 eq 18] (the trapezoid over the piece, in the region's index),
    /// the flux times `1 - R` at every surface it passes; the reflected
    /// `R` goes on as a branch of its own ([`Fresnel::Traced`]) or is
    /// counted as reflected.
    ///
    /// In a region of a constant index that does not absorb the photon
    /// goes straight, so up to `most` steps are taken as one ([`Self::run`]):
    /// on to where it leaves the grid, or to the step in which it meets a
    /// surface, which then ends where that step would have (the clock stays
    /// on whole steps). Returns how many steps were taken.
    fn sharp_step(
        &self,
        regions: &Regions,
        fresnel: Fresnel,
        ray: &mut SharpRay,
        flux: &mut [f64; 3],
        most: usize,
        t: &mut Tally,
    ) -> usize {
        let per_index = |r, p| region_extinction_per_index(self.grid, regions, r, p, self.channel);
        let mut steps = self.run(regions, ray, most);
        let mut left = steps as f64 * self.dt;
        let mut used = 0.0;
        for _ in 0..16 {
            let x0 = ray.s.x;
            let r0 = ray.region;
            let st = regions.step(ray, Form::EqualTime, self.integrator, left, self.channel);
            left -= st.used;
            used += st.used;
            if steps > 1 && st.event.is_some() {
                // A surface met within the run: the rest of the step it
                // was met in, as a single step would have left it.
                steps = ((used / self.dt) as usize + 1).min(steps);
                left = steps as f64 * self.dt - used;
            }
            // The piece ends on the surface, before any refraction.
            let x1 = st.event.map_or(ray.s.x, |e| e.point);
            let depth = step_depth(
                self.grid,
                x0,
                x1,
                per_index(r0, x0),
                per_index(r0, x1),
                st.used,
            );
            self.tally.chord(x0, x1, flux, depth, self.group);
            for c in 0..3 {
                let kept = flux[c] * (-depth[c]).exp();
                t.absorbed[c] += flux[c] - kept;
                flux[c] = kept;
            }
            if let Some(e) = st.event.filter(|e| fresnel != Fresnel::Off && !e.total) {
                let reflected = flux.map(|f| f * e.reflectance);
                for (f, r) in flux.iter_mut().zip(reflected) {
                    *f -= r;
                }
                if fresnel == Fresnel::Traced {
                    // The mirror image of the incident ray, from the
                    // surface back into the region it came from, its
                    // clock where the crossing's is.
                    let v = (e.incident - e.normal * (2.0 * e.incident.dot(e.normal))) * e.n1;
                    let back = SharpRay {
                        s: RayState {
                            x: e.point,
                            v,
                            opl: ray.s.opl,
                        },
                        region: e.from,
                        ahead: None,
                    };
                    t.branches.push((back, reflected));
                } else {
                    add(&mut t.reflected, &reflected);
                }
            }
            if !st.at_surface || left <= 0.0 {
                break;
            }
        }
        steps
    }

    /// How many steps of `dt` a photon may take as one straight step with
    /// sharp interfaces (at most `most`, at least one): enough to leave the
    /// grid where its region has a constant index and absorbs nothing, else
    /// one. (Where the region absorbs, what lies outside the grid does not,
    /// [`step_depth`]: those steps are taken one by one.) The step itself
    /// finds the first surface on its way, exactly as on a short step.
    fn run(&self, regions: &Regions, ray: &SharpRay, most: usize) -> usize {
        let r = ray.region;
        let m = regions.material(r);
        if most <= 1
            || !self.runs
            || !regions.uniform(r)
            || m.extinction != DVec3::ZERO
            || m.extinction_grid.is_some()
        {
            return 1;
        }
        let n = regions.index(r, ray.s.x, self.channel).0;
        let d = ray.s.v.normalize_or_zero();
        let exit = self.grid.clip_line(ray.s.x, d).map_or(0.0, |(_, t1)| t1);
        // Optical path to the grid's far side, in steps.
        ((exit * n / self.dt).ceil() as usize).clamp(1, most)
    }

    /// Whether a photon at `s` has left for good: outside the bounds, and
    /// its forward line never comes back (the wavefront's exit rule).
    #[inline]
    fn left(&self, s: &RayState) -> bool {
        !self.grid.contains(s.x)
            && self
                .grid
                .clip_line(s.x, s.v.normalize_or_zero())
                .is_none_or(|(_, t1)| t1 <= 0.0)
    }

    /// Trace one photon from `s` with flux `flux0` to its end, and the
    /// branches its reflections start.
    fn trace(&self, s: RayState, flux0: [f64; 3], t: &mut Tally) {
        t.photons += 1;
        add(&mut t.entered, &flux0);
        // The wavefront analyses its patches once before the first step.
        if self.left(&s) {
            t.exits += 1;
            add(&mut t.exited, &flux0);
            return;
        }
        let region = self.sharp.and_then(|(r, _)| r.at(s.x));
        self.follow(
            SharpRay {
                s,
                region,
                ahead: None,
            },
            flux0,
            flux0,
            t,
        );
        // Depth first, in the order the reflections happened: the same
        // whatever the threads.
        while let Some((ray, flux)) = t.branches.pop() {
            t.reflections += 1;
            self.follow(ray, flux, flux0, t);
        }
    }

    /// Follow one branch of a photon (with `flux0`, what it was emitted
    /// with) to its end.
    fn follow(&self, mut ray: SharpRay, mut flux: [f64; 3], flux0: [f64; 3], t: &mut Tally) {
        // sigma_t / n at the photon, kept from the end of the last step.
        let mut before = None;
        let mut steps = 0;
        loop {
            // A branch too faint to follow ends before its first step:
            // a run would carry it to the next surface, whose reflection
            // would start another.
            if steps == 0 && (0..3).all(|c| flux[c] <= self.threshold * flux0[c]) {
                t.thresholded += 1;
                add(&mut t.culled, &flux);
                break;
            }
            if steps >= self.max_steps {
                t.step_limit += 1;
                add(&mut t.trapped, &flux);
                break;
            }
            let most = self.max_steps - steps;
            let x0 = ray.s.x;
            if let Some((regions, fresnel)) = self.sharp {
                steps += self.sharp_step(regions, fresnel, &mut ray, &mut flux, most, t);
            } else if let Some(n) = self.empty.index_at(x0) {
                let s = &mut ray.s;
                // Empty space, as `propagate` skips it: straight steps in a
                // constant index, without loss, as many at once as stay
                // within the empty blocks around the photon (one chord).
                let unit = self.dt / n;
                let k = if self.runs {
                    ((self.empty.reach(x0) / unit) as usize).clamp(1, most)
                } else {
                    1
                };
                s.v = s.v.normalize_or_zero() * n;
                s.x += s.v * (k as f64 * self.dt / (n * n));
                s.opl += k as f64 * self.dt;
                self.tally.chord(x0, s.x, &flux, DVec3::ZERO, self.group);
                before = None;
                steps += k;
            } else {
                steps += 1;
                let s = &mut ray.s;
                let b = before.unwrap_or_else(|| self.extinction_per_index(x0));
                // On the eikonal shell |v| = n, like the wavefront's corners.
                match self.integrator {
                    Integrator::Euler => {
                        step_euler_on_shell(&self.field, Form::EqualTime, s, self.dt)
                    }
                    _ => step_rk4_on_shell(&self.field, Form::EqualTime, s, self.dt),
                }
                let after = self.extinction_per_index(s.x);
                before = Some(after);
                // [Ihrke07 eq 18] over one step, exactly as for a patch.
                let depth = step_depth(&self.medium.geometry, x0, s.x, b, after, self.dt);
                self.tally.chord(x0, s.x, &flux, depth, self.group);
                for c in 0..3 {
                    let kept = flux[c] * (-depth[c]).exp();
                    t.absorbed[c] += flux[c] - kept;
                    flux[c] = kept;
                }
                // Fresnel over the step, exactly as for a patch.
                if let Some(faces) = self.interfaces {
                    let tr = faces.transmittance(
                        self.medium,
                        &self.field,
                        (x0 + s.x) * 0.5,
                        s.v,
                        s.x - x0,
                        self.channel,
                    );
                    if tr < 1.0 {
                        for (f, r) in flux.iter_mut().zip(t.reflected.iter_mut()) {
                            let kept = *f * tr;
                            *r += *f - kept;
                            *f = kept;
                        }
                    }
                }
            }
            if self.left(&ray.s) {
                t.exits += 1;
                add(&mut t.exited, &flux);
                break;
            }
            if (0..3).all(|c| flux[c] <= self.threshold * flux0[c]) {
                t.thresholded += 1;
                add(&mut t.culled, &flux);
                break;
            }
        }
        t.steps = t.steps.max(steps);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn random_numbers_are_uniform_and_seeded() {
        let mut r = stream(mix(7), 3);
        let xs: Vec<f64> = (0..100_000).map(|_| r.unit()).collect();
        assert!(xs.iter().all(|&x| (0.0..1.0).contains(&x)));
        let mean = xs.iter().sum::<f64>() / xs.len() as f64;
        // Standard error of the mean: 1 / sqrt(12 * 1e5) = 9.1e-4.
        assert!((mean - 0.5).abs() < 4e-3, "{mean}");
        let first = |key, i| stream(key, i).unit();
        assert_eq!(first(mix(7), 3), xs[0]);
        assert_ne!(first(mix(7), 4), xs[0]);
        assert_ne!(first(mix(8), 3), xs[0]);
    }

    #[test]
    fn strata_tile_the_square_in_equal_areas() {
        for (count, aspect) in [
            (1, 1.0),
            (7, 1.0),
            (1000, 2.5),
            (1023, 1.0 / PI),
            (5, 100.0),
        ] {
            let strata = Strata::new(count, aspect);
            // Rows hold every photon once, in order, and have heights in
            // proportion to their photons: cells of equal area 1 / count.
            let mut covered = 0;
            for r in 0..strata.rows {
                let (lo, hi) = (strata.start(r), strata.start(r + 1));
                assert_eq!(lo, covered);
                assert!(hi > lo, "empty row {r} of {count}");
                covered = hi;
            }
            assert_eq!(covered, count as u128);
            let mut rng = stream(1, 2);
            let mut sum = (0.0, 0.0);
            for i in 0..count {
                let (a, b) = strata.draw(i, &mut rng);
                assert!((0.0..=1.0).contains(&a) && (0.0..=1.0).contains(&b));
                sum = (sum.0 + a, sum.1 + b);
            }
            // A stratified sample's mean is within a cell of 1/2.
            let n = count as f64;
            let cell = (1.0 / n).sqrt().max(1.0 / strata.rows as f64);
            assert!((sum.0 / n - 0.5).abs() <= cell && (sum.1 / n - 0.5).abs() <= cell);
        }
    }

    #[test]
    fn no_photons_is_refused() {
        let grid = GridGeometry::new([4, 4, 4], DVec3::ZERO, DVec3::ONE);
        let scene = eikon_grid::Scene::parse(
            "[grid]\nresolution = 4\nmin = [0, 0, 0]\nmax = [1, 1, 1]\n",
            "test",
        )
        .unwrap();
        let m = Medium::build(&scene).unwrap();
        assert_eq!(m.geometry, grid);
        let light = Light::Point {
            position: DVec3::splat(0.5),
            power: DVec3::ONE,
        };
        let e = simulate_photons(&light, &m, 0, 1, &Options::default()).unwrap_err();
        assert!(e.to_string().starts_with("photons"), "{e}");
    }

    /// Straight steps taken as one run change nothing but rounding: the
    /// same photons end the same ways, the longest takes as many steps, and
    /// the volumes agree to the fixed point's rounding. A clear glass ball
    /// (runs inside it, to and between its surfaces, reflections traced as
    /// branches) and an absorbing one (steps one by one), with sharp
    /// interfaces and smoothed (runs through the empty blocks only), under
    /// a point light.
    #[test]
    fn runs_through_constant_space_match_single_steps() {
        let text = "[grid]\nresolution = 24\nmin = [-1, -1, -1]\nmax = [1, 1, 1]\n\
            [[object]]\nshape = { type = \"sphere\", center = [-0.35, 0.1, 0.0], radius = 0.4 }\nindex = 1.5\n\
            [[object]]\nshape = { type = \"sphere\", center = [0.45, -0.2, 0.1], radius = 0.35 }\nindex = 1.4\nextinction = [1.0, 2.0, 3.0]\n";
        let light = Light::Point {
            position: DVec3::new(0.05, 0.8, -0.1),
            power: DVec3::ONE,
        };
        for interfaces in ["sharp", "smoothed"] {
            let scene = eikon_grid::Scene::parse(
                &text.replace("[grid]", &format!("[grid]\ninterfaces = \"{interfaces}\"")),
                "test",
            )
            .unwrap();
            let m = Medium::build(&scene).unwrap();
            let regions = (interfaces == "sharp").then(|| Regions::new(&scene));
            let opts = Options::default();
            let run = |runs| trace_photons(&light, &m, regions.as_ref(), 20_000, 3, &opts, runs);
            let (a, sa) = run(true).unwrap();
            let (b, sb) = run(false).unwrap();
            let counts =
                |s: &Summary| (s.emitted, s.exited, s.absorbed, s.step_limit, s.reflections);
            assert_eq!(counts(&sa), counts(&sb), "{interfaces}");
            assert!(sa.reflections > 0 || interfaces == "smoothed");
            assert!(
                sa.steps.abs_diff(sb.steps) <= 1,
                "{} vs {}",
                sa.steps,
                sb.steps
            );
            for c in 0..3 {
                let rel = |x: f64, y: f64| (x - y).abs() / y.abs().max(1e-300);
                assert!(rel(sa.absorbed_power[c], sb.absorbed_power[c]) < 1e-9);
                assert!(rel(sa.exited_power[c], sb.exited_power[c]) < 1e-9);
            }
            let top = b.fluence.iter().fold(0.0f32, |m, &x| m.max(x));
            assert!(top > 0.0);
            let worst = a
                .fluence
                .iter()
                .zip(&b.fluence)
                .map(|(x, y)| (x - y).abs() / top)
                .fold(0.0f32, f32::max);
            println!("{interfaces}: largest fluence difference {worst:.2e} of the largest");
            assert!(worst < 1e-5, "{interfaces}: {worst}");
        }
    }

    #[test]
    fn a_point_light_in_vacuum_sends_all_its_power_out() {
        let scene = eikon_grid::Scene::parse(
            "[grid]\nresolution = 16\nmin = [-1, -1, -1]\nmax = [1, 1, 1]\n",
            "test",
        )
        .unwrap();
        let m = Medium::build(&scene).unwrap();
        let light = Light::Point {
            position: DVec3::new(0.1, -0.2, 0.05),
            power: DVec3::new(3.0, 2.0, 1.0),
        };
        let (_, s) = simulate_photons(&light, &m, 5000, 9, &Options::default()).unwrap();
        assert_eq!((s.emitted, s.exited), (5000, 5000));
        for (c, p) in [3.0, 2.0, 1.0].into_iter().enumerate() {
            assert!((s.entered[c] - p).abs() < 1e-12 * p);
            assert!((s.exited_power[c] - p).abs() < 1e-12 * p);
        }
        assert!(s.energy_imbalance() < 1e-12);
    }
}
