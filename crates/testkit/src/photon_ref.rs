//! An independent photon tracer (issue 16): a second, small photon code,
//! written from scratch to check `eikon_wavefront`'s light volumes and its
//! own photon baseline (`eikon_wavefront::photons`) against something that
//! shares none of their code.
//!
//! It uses nothing of `eikon_wavefront` nor of `eikon_grid`'s ray, region,
//! surface, field or RNG code: its own generator (xoshiro256** seeded by
//! SplitMix64), its own ray-sphere intersection, Snell refraction,
//! unpolarised Fresnel reflectance, Beer-Lambert attenuation and a 3D DDA
//! (Amanatides-Woo) for the track-length estimator. Only glam's vectors,
//! ndarray and rayon come from elsewhere.
//!
//! # Model
//! * A regular grid box `[min, max]` with `dims` cells; the ambient has
//!   index 1 and no extinction; nothing exists outside the box (a photon
//!   that leaves it is gone).
//! * At most one sphere (centre, radius, index, RGB extinction per unit
//!   length). At its surface a photon is reflected with the unpolarised
//!   Fresnel reflectance `R = (Rs + Rp) / 2` (total internal reflection:
//!   `R = 1`) and refracted by Snell's law otherwise: a stochastic choice,
//!   so the weight is unchanged. Any number of interactions up to
//!   [`MAX_INTERACTIONS`]; a photon past it is counted as capped.
//! * Inside the sphere the weight falls as `exp(-sigma s)` per channel
//!   (expected-value absorption); the deposit over a chord of length `l`
//!   is the exact integral `w (1 - exp(-sigma l)) / sigma`.
//! * Lights: directional (`irradiance` in W per unit area perpendicular to
//!   the direction, eikon's `power` of a directional light), a collimated
//!   disc beam (total power), an isotropic point light (power in W).
//!   Photons are drawn independently (no stratification): a directional
//!   light's origins are uniform over the rectangle that covers the box's
//!   projection on the plane perpendicular to the direction, each carrying
//!   `irradiance * area / N`; rays that miss the box carry their weight
//!   nowhere (not entered).
//! * Estimator: per cell, the sum over photons of weight times the chord
//!   length through the cell, over the cell volume: the cell average of
//!   the fluence rate in W per unit area, the units and layout
//!   `(nx, ny, nz, 3)` of `eikon_wavefront::LightVolume::fluence`.
//!
//! # Determinism
//! Photons go in batches of [`BATCH`], batch `b` with its own generator
//! seeded from `(seed, b)`; batch volumes are traced in parallel and summed
//! in batch order, so the result is bitwise the same for any thread count.

use glam::DVec3;
use ndarray::Array4;
use rayon::prelude::*;

/// Photons per batch (one generator each).
pub const BATCH: u64 = 1 << 15;
/// Batches traced at once (each holds its own volume until it is summed).
const GROUP: usize = 8;
/// Most sphere interactions of one photon.
pub const MAX_INTERACTIONS: u32 = 256;

/// The grid: a box and its cells.
#[derive(Clone, Copy, Debug)]
pub struct Grid {
    /// Lower corner.
    pub min: DVec3,
    /// Upper corner.
    pub max: DVec3,
    /// Cells along x, y, z.
    pub dims: [usize; 3],
}

impl Grid {
    /// Cell edge lengths.
    pub fn cell(&self) -> DVec3 {
        (self.max - self.min)
            / DVec3::new(
                self.dims[0] as f64,
                self.dims[1] as f64,
                self.dims[2] as f64,
            )
    }

    /// Centre of cell `(i, j, k)`.
    pub fn centre(&self, i: usize, j: usize, k: usize) -> DVec3 {
        self.min + (DVec3::new(i as f64, j as f64, k as f64) + 0.5) * self.cell()
    }

    /// Entry and exit distances of the line `o + t d` through the box
    /// (slab test), `None` where it misses.
    fn clip(&self, o: DVec3, d: DVec3) -> Option<(f64, f64)> {
        let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
        for a in 0..3 {
            if d[a] == 0.0 {
                if o[a] < self.min[a] || o[a] > self.max[a] {
                    return None;
                }
                continue;
            }
            let (ta, tb) = ((self.min[a] - o[a]) / d[a], (self.max[a] - o[a]) / d[a]);
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
        (t0 < t1).then_some((t0, t1))
    }

    /// Distance from `x` (inside) along `d` to the box's boundary.
    fn exit(&self, x: DVec3, d: DVec3) -> f64 {
        let mut t = f64::INFINITY;
        for a in 0..3 {
            if d[a] > 0.0 {
                t = t.min((self.max[a] - x[a]) / d[a]);
            } else if d[a] < 0.0 {
                t = t.min((self.min[a] - x[a]) / d[a]);
            }
        }
        t.max(0.0)
    }
}

/// A homogeneous sphere.
#[derive(Clone, Copy, Debug)]
pub struct Sphere {
    /// Centre.
    pub centre: DVec3,
    /// Radius.
    pub radius: f64,
    /// Refractive index (the ambient's is 1).
    pub index: f64,
    /// RGB extinction per unit length (all of it absorption).
    pub extinction: [f64; 3],
}

/// The light.
#[derive(Clone, Copy, Debug)]
pub enum Light {
    /// A plane wave over the whole box: `irradiance` in W per unit area
    /// perpendicular to `direction`.
    Directional {
        /// Travel direction (normalised here).
        direction: DVec3,
        /// RGB irradiance.
        irradiance: [f64; 3],
    },
    /// A collimated beam of uniform irradiance over a disc of `radius`
    /// centred on `centre`, perpendicular to `direction`.
    Beam {
        /// A point on the beam's axis (outside or inside the box).
        centre: DVec3,
        /// Travel direction (normalised here).
        direction: DVec3,
        /// Disc radius.
        radius: f64,
        /// RGB total power, W.
        power: [f64; 3],
    },
    /// An isotropic point light.
    Point {
        /// Position.
        position: DVec3,
        /// RGB power, W.
        power: [f64; 3],
    },
}

/// What the tracer traces.
#[derive(Clone, Copy, Debug)]
pub struct Scene {
    /// The grid box.
    pub grid: Grid,
    /// The sphere, if any.
    pub sphere: Option<Sphere>,
    /// The light.
    pub light: Light,
    /// Trace reflected photons (physics); `false` drops them where they
    /// reflect, counted in [`Account::dropped`] (what the wavefront does
    /// with its Fresnel reflection).
    pub reflections: bool,
}

/// Where the power went, RGB in W, and event counts.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Account {
    /// Photons drawn.
    pub emitted: u64,
    /// Photons that entered the box.
    pub entered_photons: u64,
    /// Power that entered the box.
    pub entered: [f64; 3],
    /// Power absorbed in the sphere.
    pub absorbed: [f64; 3],
    /// Power carried out of the box.
    pub left: [f64; 3],
    /// Power of reflected photons dropped (`reflections == false`).
    pub dropped: [f64; 3],
    /// Power of photons stopped at [`MAX_INTERACTIONS`].
    pub capped: [f64; 3],
    /// Photons stopped at [`MAX_INTERACTIONS`].
    pub capped_photons: u64,
    /// Sphere interactions (reflections and refractions).
    pub interactions: u64,
    /// Of them, reflections (total internal ones included).
    pub reflections: u64,
    /// Photons whose path met the sphere at least once.
    pub first_hits: u64,
    /// Of them, those reflected at that first meeting.
    pub first_reflections: u64,
    /// Most interactions of one photon.
    pub most_interactions: u32,
}

impl Account {
    fn add(&mut self, o: &Account) {
        self.emitted += o.emitted;
        self.entered_photons += o.entered_photons;
        for c in 0..3 {
            self.entered[c] += o.entered[c];
            self.absorbed[c] += o.absorbed[c];
            self.left[c] += o.left[c];
            self.dropped[c] += o.dropped[c];
            self.capped[c] += o.capped[c];
        }
        self.capped_photons += o.capped_photons;
        self.interactions += o.interactions;
        self.reflections += o.reflections;
        self.first_hits += o.first_hits;
        self.first_reflections += o.first_reflections;
        self.most_interactions = self.most_interactions.max(o.most_interactions);
    }

    /// Largest relative imbalance over the channels of
    /// `entered = absorbed + left + dropped + capped`.
    pub fn imbalance(&self) -> f64 {
        (0..3)
            .map(|c| {
                let out = self.absorbed[c] + self.left[c] + self.dropped[c] + self.capped[c];
                (self.entered[c] - out).abs() / self.entered[c].abs().max(f64::MIN_POSITIVE)
            })
            .fold(0.0, f64::max)
    }
}

/// A run's result.
pub struct Output {
    /// RGB fluence rate per cell (cell average), `(nx, ny, nz, 3)`.
    pub fluence: Array4<f64>,
    /// Where the power went.
    pub account: Account,
}

/// SplitMix64 step: seeds and batch seeds.
fn splitmix64(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// xoshiro256** (Blackman and Vigna), seeded by SplitMix64.
pub struct Rng([u64; 4]);

impl Rng {
    /// A generator for batch `stream` of run `seed`.
    pub fn new(seed: u64, stream: u64) -> Rng {
        let mut sm = seed ^ 0x5851_F42D_4C95_7F2D;
        let mut mix = splitmix64(&mut sm) ^ stream.wrapping_mul(0xD1B5_4A32_D192_ED03);
        Rng([0; 4].map(|_| splitmix64(&mut mix)))
    }

    /// The next 64 bits.
    pub fn next_u64(&mut self) -> u64 {
        let s = &mut self.0;
        let out = s[1].wrapping_mul(5).rotate_left(7).wrapping_mul(9);
        let t = s[1] << 17;
        s[2] ^= s[0];
        s[3] ^= s[1];
        s[1] ^= s[2];
        s[0] ^= s[3];
        s[2] ^= t;
        s[3] = s[3].rotate_left(45);
        out
    }

    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

/// Two unit vectors perpendicular to unit `d` and to each other.
fn basis(d: DVec3) -> (DVec3, DVec3) {
    let a = if d.x.abs() < 0.6 { DVec3::X } else { DVec3::Y };
    let u = (a - d * a.dot(d)).normalize();
    (u, d.cross(u))
}

/// Unpolarised Fresnel reflectance for cosine of incidence `cos_i` going
/// from index `n1` into `n2`, with the cosine of refraction (`None`: total
/// internal reflection).
pub fn fresnel(cos_i: f64, n1: f64, n2: f64) -> (f64, Option<f64>) {
    let eta = n1 / n2;
    let sin2_t = eta * eta * (1.0 - cos_i * cos_i);
    if sin2_t >= 1.0 {
        return (1.0, None);
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let rs = (n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t);
    let rp = (n2 * cos_i - n1 * cos_t) / (n2 * cos_i + n1 * cos_t);
    (0.5 * (rs * rs + rp * rp), Some(cos_t))
}

/// A batch's tally: unnormalised deposits (weight times length) and the
/// account.
struct Tally {
    volume: Vec<f64>,
    account: Account,
}

/// What a light emits, prepared once per run.
struct Emitter {
    light: Light,
    /// Per-photon weight, RGB.
    weight: [f64; 3],
    /// Directional: origin rectangle `centre + a u + b v`, `a` in
    /// `[a0, a1]`, `b` in `[b0, b1]` (`centre` one box diagonal upstream
    /// of the box's centre), and the direction.
    rect: (DVec3, DVec3, DVec3, [f64; 4], DVec3),
}

impl Emitter {
    fn new(scene: &Scene, photons: u64) -> Emitter {
        let g = &scene.grid;
        let n = photons.max(1) as f64;
        let centre = 0.5 * (g.min + g.max);
        let mut rect = (centre, DVec3::X, DVec3::Y, [0.0; 4], DVec3::Z);
        let weight = match scene.light {
            Light::Directional {
                direction,
                irradiance,
            } => {
                let d = direction.normalize();
                let (u, v) = basis(d);
                let mut r = [
                    f64::INFINITY,
                    f64::NEG_INFINITY,
                    f64::INFINITY,
                    f64::NEG_INFINITY,
                ];
                for corner in 0..8 {
                    let p = DVec3::new(
                        if corner & 1 == 0 { g.min.x } else { g.max.x },
                        if corner & 2 == 0 { g.min.y } else { g.max.y },
                        if corner & 4 == 0 { g.min.z } else { g.max.z },
                    ) - centre;
                    r[0] = r[0].min(p.dot(u));
                    r[1] = r[1].max(p.dot(u));
                    r[2] = r[2].min(p.dot(v));
                    r[3] = r[3].max(p.dot(v));
                }
                // Origins upstream of the whole box.
                rect = (centre - d * (g.max - g.min).length(), u, v, r, d);
                let area = (r[1] - r[0]) * (r[3] - r[2]);
                irradiance.map(|e| e * area / n)
            }
            Light::Beam { power, .. } | Light::Point { power, .. } => power.map(|p| p / n),
        };
        Emitter {
            light: scene.light,
            weight,
            rect,
        }
    }

    /// One photon's origin and direction (the origin may lie outside the
    /// box).
    fn draw(&self, rng: &mut Rng) -> (DVec3, DVec3) {
        match self.light {
            Light::Directional { .. } => {
                let (c, u, v, r, d) = self.rect;
                let a = r[0] + (r[1] - r[0]) * rng.uniform();
                let b = r[2] + (r[3] - r[2]) * rng.uniform();
                (c + a * u + b * v, d)
            }
            Light::Beam {
                centre,
                direction,
                radius,
                ..
            } => {
                let d = direction.normalize();
                let (u, v) = basis(d);
                let r = radius * rng.uniform().sqrt();
                let phi = std::f64::consts::TAU * rng.uniform();
                (centre + r * (phi.cos() * u + phi.sin() * v), d)
            }
            Light::Point { position, .. } => {
                let z = 1.0 - 2.0 * rng.uniform();
                let s = (1.0 - z * z).max(0.0).sqrt();
                let phi = std::f64::consts::TAU * rng.uniform();
                (position, DVec3::new(s * phi.cos(), s * phi.sin(), z))
            }
        }
    }
}

/// The tracer for one scene.
struct Tracer<'a> {
    scene: &'a Scene,
    cell: DVec3,
}

impl Tracer<'_> {
    /// Deposit the segment `x + t d`, `t` in `[0, len]`, cell by cell
    /// (3D DDA), attenuating `w` by `sigma` if given.
    fn deposit(
        &self,
        x: DVec3,
        d: DVec3,
        len: f64,
        w: &mut [f64; 3],
        sigma: Option<[f64; 3]>,
        tally: &mut Tally,
    ) {
        if len <= 0.0 {
            return;
        }
        let g = &self.scene.grid;
        let [nx, ny, nz] = g.dims;
        let n = [nx as i64, ny as i64, nz as i64];
        let mut cell = [0i64; 3];
        let mut step = [0i64; 3];
        let mut t_max = [f64::INFINITY; 3];
        for a in 0..3 {
            let u = (x[a] - g.min[a]) / self.cell[a];
            cell[a] = (u.floor() as i64).clamp(0, n[a] - 1);
            if d[a] > 0.0 {
                step[a] = 1;
            } else if d[a] < 0.0 {
                step[a] = -1;
            }
        }
        let boundary = |a: usize, c: i64, s: i64| -> f64 {
            let edge = g.min[a] + (c + i64::from(s > 0)) as f64 * self.cell[a];
            (edge - x[a]) / d[a]
        };
        for a in 0..3 {
            if step[a] != 0 {
                t_max[a] = boundary(a, cell[a], step[a]);
            }
        }
        let mut t = 0.0;
        loop {
            let a = if t_max[0] <= t_max[1] && t_max[0] <= t_max[2] {
                0
            } else if t_max[1] <= t_max[2] {
                1
            } else {
                2
            };
            let t_next = t_max[a].min(len);
            let chord = t_next - t;
            if chord > 0.0 {
                let q = (((cell[0] * n[1] + cell[1]) * n[2] + cell[2]) * 3) as usize;
                let v = &mut tally.volume[q..q + 3];
                match sigma {
                    None => (0..3).for_each(|c| v[c] += w[c] * chord),
                    Some(s) => {
                        for c in 0..3 {
                            if s[c] > 0.0 {
                                let lost = -(-s[c] * chord).exp_m1();
                                v[c] += w[c] * lost / s[c];
                                let gone = w[c] * lost;
                                tally.account.absorbed[c] += gone;
                                w[c] -= gone;
                            } else {
                                v[c] += w[c] * chord;
                            }
                        }
                    }
                }
                t = t_next;
            }
            if t_next >= len {
                return;
            }
            cell[a] += step[a];
            if cell[a] < 0 || cell[a] >= n[a] {
                return;
            }
            t_max[a] = boundary(a, cell[a], step[a]);
        }
    }

    /// Trace one photon from `o` along unit `d` with weight `w`.
    fn photon(&self, o: DVec3, d: DVec3, mut w: [f64; 3], rng: &mut Rng, tally: &mut Tally) {
        let g = &self.scene.grid;
        let acc_emit = &mut tally.account;
        acc_emit.emitted += 1;
        let Some((t0, t1)) = g.clip(o, d) else {
            return;
        };
        if t1 <= 0.0 {
            return;
        }
        let mut x = o + d * t0.max(0.0);
        let mut d = d;
        acc_emit.entered_photons += 1;
        (0..3).for_each(|c| acc_emit.entered[c] += w[c]);
        let mut inside = self
            .scene
            .sphere
            .is_some_and(|s| (x - s.centre).length_squared() < s.radius * s.radius);
        let mut hits = 0u32;
        loop {
            let exit = g.exit(x, d);
            let hit = self.scene.sphere.and_then(|s| {
                let oc = x - s.centre;
                let b = oc.dot(d);
                let cc = oc.dot(oc) - s.radius * s.radius;
                let disc = b * b - cc;
                let t = if inside {
                    // The far root; a ray from inside always meets it.
                    Some((-b + disc.max(0.0).sqrt()).max(0.0))
                } else if disc < 0.0 {
                    None
                } else {
                    // The near root, ahead of the surface just left.
                    let t = -b - disc.sqrt();
                    (t > 1e-12 * s.radius).then_some(t)
                };
                t.map(|t| (t, s))
            });
            let sigma = if inside {
                self.scene.sphere.map(|s| s.extinction)
            } else {
                None
            };
            let Some((t, s)) = hit.filter(|(t, _)| *t < exit) else {
                self.deposit(x, d, exit, &mut w, sigma, tally);
                (0..3).for_each(|c| tally.account.left[c] += w[c]);
                tally.account.most_interactions = tally.account.most_interactions.max(hits);
                return;
            };
            self.deposit(x, d, t, &mut w, sigma, tally);
            x += d * t;
            if hits == MAX_INTERACTIONS {
                (0..3).for_each(|c| tally.account.capped[c] += w[c]);
                tally.account.capped_photons += 1;
                tally.account.most_interactions = tally.account.most_interactions.max(hits);
                return;
            }
            hits += 1;
            let acc = &mut tally.account;
            acc.interactions += 1;
            let outward = (x - s.centre) / s.radius;
            // The normal on the incoming side.
            let nf = if inside { -outward } else { outward };
            let (n1, n2) = if inside {
                (s.index, 1.0)
            } else {
                (1.0, s.index)
            };
            let cos_i = (-d.dot(nf)).clamp(0.0, 1.0);
            let (r, cos_t) = fresnel(cos_i, n1, n2);
            let reflect = cos_t.is_none() || rng.uniform() < r;
            if hits == 1 {
                acc.first_hits += 1;
                acc.first_reflections += u64::from(reflect);
            }
            if reflect {
                acc.reflections += 1;
                if !self.scene.reflections {
                    (0..3).for_each(|c| acc.dropped[c] += w[c]);
                    acc.most_interactions = acc.most_interactions.max(hits);
                    return;
                }
                d = (d + 2.0 * cos_i * nf).normalize();
            } else {
                let eta = n1 / n2;
                let cos_t = cos_t.expect("refraction has a cosine");
                d = (eta * d + (eta * cos_i - cos_t) * nf).normalize();
                inside = !inside;
            }
        }
    }

    fn batch(&self, emitter: &Emitter, seed: u64, b: u64, count: u64) -> Tally {
        let g = &self.scene.grid;
        let mut tally = Tally {
            volume: vec![0.0; g.dims[0] * g.dims[1] * g.dims[2] * 3],
            account: Account::default(),
        };
        let mut rng = Rng::new(seed, b);
        for _ in 0..count {
            let (o, d) = emitter.draw(&mut rng);
            self.photon(o, d, emitter.weight, &mut rng, &mut tally);
        }
        tally
    }
}

/// Trace `photons` photons of `scene` with `seed`: the fluence and the
/// account. The same for any number of rayon threads.
pub fn simulate(scene: &Scene, photons: u64, seed: u64) -> Output {
    let g = &scene.grid;
    let tracer = Tracer {
        scene,
        cell: g.cell(),
    };
    let emitter = Emitter::new(scene, photons);
    let batches: Vec<(u64, u64)> = (0..photons.div_ceil(BATCH))
        .map(|b| (b, BATCH.min(photons - b * BATCH)))
        .collect();
    let mut volume = vec![0.0; g.dims[0] * g.dims[1] * g.dims[2] * 3];
    let mut account = Account::default();
    for group in batches.chunks(GROUP) {
        let tallies: Vec<Tally> = group
            .par_iter()
            .map(|&(b, count)| tracer.batch(&emitter, seed, b, count))
            .collect();
        for t in &tallies {
            volume.iter_mut().zip(&t.volume).for_each(|(v, x)| *v += x);
            account.add(&t.account);
        }
    }
    let cell = tracer.cell;
    let inv_volume = 1.0 / (cell.x * cell.y * cell.z);
    volume.iter_mut().for_each(|v| *v *= inv_volume);
    Output {
        fluence: Array4::from_shape_vec((g.dims[0], g.dims[1], g.dims[2], 3), volume)
            .expect("the volume fits the grid"),
        account,
    }
}

#[cfg(test)]
// A channel indexes several arrays at once in these checks.
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    fn cube(n: usize) -> Grid {
        Grid {
            min: DVec3::splat(-1.0),
            max: DVec3::splat(1.0),
            dims: [n; 3],
        }
    }

    /// A bound of one cell's standard deviation: each photon adds at most
    /// `w lmax / V` to a cell whose mean is `phi`, so the variance is at
    /// most `w lmax phi / V`.
    fn sigma_bound(w: f64, lmax: f64, volume: f64, phi: f64) -> f64 {
        (w * lmax * phi / volume).sqrt()
    }

    #[test]
    fn directional_light_in_an_empty_box_reads_its_irradiance() {
        let grid = cube(8);
        let e = [2.0, 1.0, 0.5];
        let scene = Scene {
            grid,
            sphere: None,
            light: Light::Directional {
                direction: DVec3::new(0.3, -1.0, 0.45),
                irradiance: e,
            },
            reflections: true,
        };
        let n = 1u64 << 20;
        let out = simulate(&scene, n, 7);
        let emitter = Emitter::new(&scene, n);
        let cell = grid.cell();
        let volume = cell.x * cell.y * cell.z;
        let lmax = cell.length();
        for c in 0..3 {
            let w = emitter.weight[c];
            let sd = sigma_bound(w, lmax, volume, e[c]);
            for (idx, &phi) in out.fluence.index_axis(ndarray::Axis(3), c).indexed_iter() {
                assert!(
                    (phi - e[c]).abs() < 5.0 * sd,
                    "cell {idx:?} channel {c}: {phi} vs {} (5 sigma = {})",
                    e[c],
                    5.0 * sd
                );
            }
            // The mean over all cells: each photon adds at most w D / (M V).
            let m = grid.dims.iter().product::<usize>() as f64;
            let mean = out.fluence.index_axis(ndarray::Axis(3), c).sum() / m;
            let diag = (grid.max - grid.min).length();
            let sd_mean = (w * diag * e[c] / (m * volume)).sqrt();
            assert!(
                (mean - e[c]).abs() < 5.0 * sd_mean,
                "channel {c}: mean {mean} vs {} (5 sigma = {})",
                e[c],
                5.0 * sd_mean
            );
        }
    }

    /// Gauss-Legendre, 4 points on [-1, 1].
    const GL4: [(f64, f64); 4] = [
        (-0.861_136_311_594_052_6, 0.347_854_845_137_453_9),
        (-0.339_981_043_584_856_3, 0.652_145_154_862_546_1),
        (0.339_981_043_584_856_3, 0.652_145_154_862_546_1),
        (0.861_136_311_594_052_6, 0.347_854_845_137_453_9),
    ];

    #[test]
    fn point_light_in_an_empty_box_falls_as_inverse_square() {
        let grid = cube(8);
        let p = DVec3::new(0.11, -0.07, 0.05);
        let power = [1.0, 3.0, 0.5];
        let scene = Scene {
            grid,
            sphere: None,
            light: Light::Point { position: p, power },
            reflections: true,
        };
        let n = 1u64 << 22;
        let out = simulate(&scene, n, 11);
        let cell = grid.cell();
        let volume = cell.x * cell.y * cell.z;
        let mut checked = 0;
        for i in 0..8 {
            for j in 0..8 {
                for k in 0..8 {
                    let c0 = grid.centre(i, j, k);
                    if (c0 - p).length() < 2.0 * cell.x {
                        continue;
                    }
                    // The exact cell average of 1 / (4 pi r^2).
                    let mut avg = 0.0;
                    for (a, wa) in GL4 {
                        for (b, wb) in GL4 {
                            for (d, wd) in GL4 {
                                let x = c0 + 0.5 * cell * DVec3::new(a, b, d);
                                avg += wa * wb * wd / (4.0 * PI * (x - p).length_squared());
                            }
                        }
                    }
                    avg /= 8.0;
                    for c in 0..3 {
                        let want = power[c] * avg;
                        let sd = sigma_bound(power[c] / n as f64, cell.length(), volume, want);
                        let got = out.fluence[[i, j, k, c]];
                        assert!(
                            (got - want).abs() < 5.0 * sd,
                            "cell ({i}, {j}, {k}) channel {c}: {got} vs {want} (5 sigma {})",
                            5.0 * sd
                        );
                    }
                    checked += 1;
                }
            }
        }
        assert!(checked > 400, "{checked} cells checked");
        // All power enters (the light is inside) and leaves.
        let acc = out.account;
        for c in 0..3 {
            assert!((acc.entered[c] - power[c]).abs() < 1e-9 * power[c]);
            assert!((acc.left[c] - power[c]).abs() < 1e-9 * power[c]);
        }
    }

    fn glass(sigma: [f64; 3]) -> Sphere {
        Sphere {
            centre: DVec3::new(0.0, 0.15, 0.0),
            radius: 0.45,
            index: 1.5,
            extinction: sigma,
        }
    }

    #[test]
    fn energy_is_conserved_and_threads_do_not_matter() {
        let lights = [
            Light::Directional {
                direction: DVec3::new(0.2, -1.0, 0.1),
                irradiance: [1.0, 1.0, 1.0],
            },
            // Outside the sphere: light from inside it beyond the critical
            // angle is held by total internal reflection for good (the
            // angle of incidence is the same at every bounce in a sphere).
            Light::Point {
                position: DVec3::new(0.1, -0.5, -0.05),
                power: [1.0, 2.0, 3.0],
            },
        ];
        for light in lights {
            let scene = Scene {
                grid: cube(16),
                sphere: Some(glass([0.8, 0.3, 2.0])),
                light,
                reflections: true,
            };
            let run = |threads: usize| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .expect("a thread pool")
                    .install(|| simulate(&scene, 3 * BATCH + 123, 5))
            };
            let (one, two) = (run(1), run(2));
            let acc = two.account;
            assert!(
                acc.imbalance() < 1e-12,
                "{acc:?}: imbalance {}",
                acc.imbalance()
            );
            assert_eq!(acc.capped_photons, 0);
            assert!(acc.interactions > 0 && acc.reflections > 0, "{acc:?}");
            assert!(acc.absorbed.iter().all(|&a| a > 0.0), "{acc:?}");
            assert_eq!(one.account, two.account);
            assert!(
                one.fluence
                    .iter()
                    .zip(two.fluence.iter())
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "1 and 2 threads differ"
            );
        }
    }

    #[test]
    fn thick_absorbing_sphere_takes_beer_lambert_from_a_narrow_beam() {
        let sigma = [0.5, 1.0, 2.0];
        let r = 0.5;
        let scene = Scene {
            grid: cube(16),
            sphere: Some(Sphere {
                centre: DVec3::ZERO,
                radius: r,
                index: 1.0,
                extinction: sigma,
            }),
            light: Light::Beam {
                centre: DVec3::new(-2.0, 0.0, 0.0),
                direction: DVec3::X,
                radius: 0.005,
                power: [1.0; 3],
            },
            reflections: true,
        };
        let out = simulate(&scene, 1 << 16, 3);
        let acc = out.account;
        assert_eq!(acc.reflections, 0);
        for c in 0..3 {
            let want = 1.0 - (-2.0 * r * sigma[c]).exp();
            let got = acc.absorbed[c] / acc.entered[c];
            assert!(
                (got - want).abs() < 2e-4 * want,
                "channel {c}: absorbed {got}, want {want}"
            );
        }
    }

    /// Fresnel's reflectance from the angles (a different form from the
    /// tracer's cosines).
    fn reflectance(theta_i: f64, n: f64) -> f64 {
        if theta_i == 0.0 {
            return ((n - 1.0) / (n + 1.0)).powi(2);
        }
        let theta_t = (theta_i.sin() / n).asin();
        let rs = ((theta_i - theta_t).sin() / (theta_i + theta_t).sin()).powi(2);
        let rp = ((theta_i - theta_t).tan() / (theta_i + theta_t).tan()).powi(2);
        0.5 * (rs + rp)
    }

    #[test]
    fn fresnel_reflects_the_right_fraction_at_the_first_surface() {
        let n = 1.5;
        let r = 0.5;
        for theta in [0.0f64, 60f64.to_radians()] {
            let b = r * theta.sin();
            let scene = Scene {
                grid: cube(8),
                sphere: Some(Sphere {
                    centre: DVec3::ZERO,
                    radius: r,
                    index: n,
                    extinction: [0.0; 3],
                }),
                light: Light::Beam {
                    centre: DVec3::new(-2.0, b, 0.0),
                    direction: DVec3::X,
                    radius: 1e-4,
                    power: [1.0; 3],
                },
                reflections: true,
            };
            let photons = 1u64 << 19;
            let acc = simulate(&scene, photons, 9).account;
            assert_eq!(acc.first_hits, photons);
            let want = reflectance(theta, n);
            let got = acc.first_reflections as f64 / acc.first_hits as f64;
            let sd = (want * (1.0 - want) / photons as f64).sqrt();
            assert!(
                (got - want).abs() < 5.0 * sd,
                "incidence {theta}: reflected {got}, want {want} (5 sigma {})",
                5.0 * sd
            );
            assert!(acc.imbalance() < 1e-12);
        }
    }
}
