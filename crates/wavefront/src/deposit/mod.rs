//! The track-length deposit: how light moving through the grid becomes a
//! [`LightVolume`], for the wavefront and the photon baseline alike.
//!
//! A straight chord from `a` to `b` that carries the RGB flux `P` at `a`
//! and loses the optical depth `tau` over its length (spread evenly along
//! it, [Ihrke07 eq 18] over one step) is cut exactly among the cells it crosses
//! (a 3D DDA). Each piece `[t_a, t_b]` of the chord (`t` from 0 at `a` to 1 at
//! `b`) adds `P |b - a| int exp(-tau t) dt` watt-units to the cell's
//! fluence (divided by the cell volume at the end, a fluence rate) and the
//! same times the chord's unit direction to its flux vector (see
//! [`volume`](crate::volume) for what the two mean).
//!
//! # Fixed point
//! The sums are integers: a fluence counter per cell and channel
//! (`u64`) and a flux-vector counter per cell, component and wavefront
//! group (`i64`, two's complement), added atomically. Integer addition
//! commutes, so the volume is bitwise the same whatever the order the
//! chords arrive in (any thread count, and the GPU's atomics). A unit is
//! `1 / units_per_crossing` of what the brightest emitted flux deposits
//! over one voxel length; rounding each piece to a unit then costs at most
//! half a unit.
//!
//! The paper's own rule, the highest-energy ray per cell ([Ihrke07 sec 5.2.2],
//! `--deposit paper`), is [`paper`].

pub mod paper;

use crate::patch::span;
use crate::volume::LightVolume;
use eikon_grid::GridGeometry;
use eikon_shader::{Consts, Module};
use glam::DVec3;
use ndarray::Array4;
use rayon::prelude::*;
use std::sync::atomic::{AtomicI64, AtomicU64, Ordering};

/// Fixed-point counters of one light volume being deposited.
pub struct Counters {
    /// `(nx, ny, nz, 3)` fluence counters in standard order.
    fluence: Vec<AtomicU64>,
    /// Per group, `(nx, ny, nz, 3)` flux-vector counters.
    flux: Vec<Vec<AtomicI64>>,
    /// Fluence units per watt-unit of length, per channel.
    scale: [f64; 3],
    /// Flux-vector units per watt-unit of length.
    flux_scale: f64,
    grid: GridGeometry,
    min: DVec3,
    /// `1 / spacing`.
    inv_spacing: DVec3,
}

impl Counters {
    /// Empty counters on `grid` for `groups` wavefronts (1, or 3 with
    /// dispersion). `max_flux` is the largest flux per channel any chord
    /// will carry; a chord of that flux one voxel long deposits
    /// `units_per_crossing` units.
    pub fn new(
        grid: &GridGeometry,
        groups: usize,
        max_flux: [f64; 3],
        units_per_crossing: f64,
    ) -> Self {
        let cells = grid.voxel_count() * 3;
        let h = grid.voxel_size();
        let scale = max_flux.map(|f| {
            if f > 0.0 && f.is_finite() {
                units_per_crossing / (f * h)
            } else {
                0.0
            }
        });
        let top = max_flux
            .iter()
            .copied()
            .filter(|f| f.is_finite())
            .fold(0.0, f64::max);
        Self {
            fluence: (0..cells).map(|_| AtomicU64::new(0)).collect(),
            flux: (0..groups)
                .map(|_| (0..cells).map(|_| AtomicI64::new(0)).collect())
                .collect(),
            scale,
            flux_scale: if top > 0.0 {
                units_per_crossing / (top * h)
            } else {
                0.0
            },
            grid: grid.clone(),
            min: grid.min,
            inv_spacing: 1.0 / grid.spacing(),
        }
    }

    /// Deposit the chord from `a` to `b` carrying `flux` at `a` and losing
    /// optical depth `depth` over it (see the module docs). `group` is the
    /// wavefront's colour channel with dispersion, `None` without.
    #[inline]
    pub fn chord(&self, a: DVec3, b: DVec3, flux: &[f64; 3], depth: DVec3, group: Option<usize>) {
        let mut direct = Direct {
            counters: self,
            group: group.unwrap_or(0),
        };
        self.chord_with(a, b, flux, depth, group, &mut direct);
    }

    /// [`Self::chord`], handing each piece's fixed-point amounts to `put`.
    #[inline]
    fn chord_with<P: Put>(
        &self,
        a: DVec3,
        b: DVec3,
        flux: &[f64; 3],
        depth: DVec3,
        group: Option<usize>,
        put: &mut P,
    ) {
        let d = b - a;
        let len = d.length();
        if !(len > 0.0 && len.is_finite()) {
            return;
        }
        // Most chords lie inside the grid: no clipping then.
        let (t0, t1) = if self.grid.contains(a) && self.grid.contains(b) {
            (0.0, 1.0)
        } else {
            let Some((t0, t1)) = self.grid.clip_line(a, d) else {
                return;
            };
            (t0.max(0.0), t1.min(1.0))
        };
        if t1 <= t0 {
            return;
        }
        // Fluence units per unit of t, per channel; flux-vector units per
        // unit of t along the chord's direction.
        let w = [0, 1, 2].map(|c| flux[c] * len * self.scale[c]);
        // The flux vector: the chord's channel with dispersion, else the
        // mean of the three channels' vectors.
        let wf = match group {
            Some(g) => {
                let mut wf = [0.0; 3];
                wf[g] = flux[g] * len * self.flux_scale;
                wf
            }
            None => flux.map(|f| f * len * self.flux_scale / 3.0),
        };
        let sink = Sink {
            w,
            wf,
            u: d / len,
            depth,
            dims: self.grid.dims,
        };
        // Cell coordinates: cell (i, j, k) spans [i, i + 1) etc.
        let g = (a - self.min) * self.inv_spacing;
        let dg = d * self.inv_spacing;
        let start = g + dg * t0;
        let dims = self.grid.dims;
        // Cell of a point in cell coordinates (truncation is floor for
        // the non-negative, and the clamp takes care of the rest).
        let cell_of = |p: DVec3| [0, 1, 2].map(|ax| (p[ax] as i64).clamp(0, dims[ax] as i64 - 1));
        let first = cell_of(start);
        if first == cell_of(g + dg * t1) {
            // A short chord within one cell: one piece (the DDA would
            // find the same).
            sink.add(first, t0, t1, put);
            return;
        }
        let mut cell = [0i64; 3];
        let mut step = [0i64; 3];
        let mut next = [f64::INFINITY; 3];
        let mut delta = [f64::INFINITY; 3];
        for ax in 0..3 {
            let hi = dims[ax] as i64 - 1;
            cell[ax] = first[ax].clamp(0, hi);
            if dg[ax] > 0.0 {
                step[ax] = 1;
                next[ax] = (cell[ax] as f64 + 1.0 - g[ax]) / dg[ax];
                delta[ax] = 1.0 / dg[ax];
            } else if dg[ax] < 0.0 {
                step[ax] = -1;
                next[ax] = (cell[ax] as f64 - g[ax]) / dg[ax];
                delta[ax] = -1.0 / dg[ax];
            }
        }
        let mut t = t0;
        loop {
            let ax = if next[0] <= next[1] && next[0] <= next[2] {
                0
            } else if next[1] <= next[2] {
                1
            } else {
                2
            };
            let end = next[ax].min(t1);
            if end > t {
                sink.add(cell, t, end, put);
            }
            if next[ax] >= t1 {
                break;
            }
            cell[ax] += step[ax];
            if cell[ax] < 0 || cell[ax] >= dims[ax] as i64 {
                break;
            }
            next[ax] += delta[ax];
            t = t.max(end);
        }
    }

    /// The fixed-point scales: fluence units per watt-unit of length, per
    /// channel, and flux-vector units per watt-unit of length (what a
    /// piece's amounts are multiplied by before they are rounded).
    pub fn scales(&self) -> ([f64; 3], f64) {
        (self.scale, self.flux_scale)
    }

    /// Add fixed-point units counted elsewhere (the GPU simulator's
    /// counters) to the fluence counters of `channel`: one value per cell,
    /// standard order. Wrapping, as the atomic adds are.
    pub fn add_fluence_units(&mut self, channel: usize, units: &[u64]) {
        assert_eq!(units.len() * 3, self.fluence.len(), "one value per cell");
        self.fluence
            .par_chunks_mut(3)
            .zip(units.par_iter())
            .for_each(|(cell, &u)| {
                let c = cell[channel].get_mut();
                *c = c.wrapping_add(u);
            });
    }

    /// Add fixed-point units counted elsewhere to component `component` of
    /// wavefront group `group`'s flux-vector counters: one value per cell,
    /// standard order, two's complement. Wrapping, as the atomic adds are.
    pub fn add_flux_units(&mut self, group: usize, component: usize, units: &[i64]) {
        let flux = &mut self.flux[group];
        assert_eq!(units.len() * 3, flux.len(), "one value per cell");
        flux.par_chunks_mut(3)
            .zip(units.par_iter())
            .for_each(|(cell, &u)| {
                let c = cell[component].get_mut();
                *c = c.wrapping_add(u);
            });
    }

    /// The finished light volume: counters back to watt-units of length,
    /// over the cell volume.
    pub fn into_volume(self) -> LightVolume {
        let Counters {
            fluence,
            flux,
            scale,
            flux_scale: fs,
            grid,
            ..
        } = self;
        let [nx, ny, nz] = grid.dims;
        let s = grid.spacing();
        let volume = s.x * s.y * s.z;
        // One array at a time, each set of counters dropped as soon as it
        // is converted: the peak holds one f32 copy, not all of them.
        let fluence: Vec<f32> = fluence
            .into_par_iter()
            .enumerate()
            .map(|(i, u)| {
                let sc = scale[i % 3];
                if sc > 0.0 {
                    (u.into_inner() as f64 / sc / volume) as f32
                } else {
                    0.0
                }
            })
            .collect();
        let flux = flux
            .into_iter()
            .map(|f| {
                let v: Vec<f32> = f
                    .into_par_iter()
                    .map(|u| {
                        if fs > 0.0 {
                            (u.into_inner() as f64 / fs / volume) as f32
                        } else {
                            0.0
                        }
                    })
                    .collect();
                Array4::from_shape_vec((nx, ny, nz, 3), v).expect("cells * 3 values")
            })
            .collect();
        LightVolume {
            fluence: Array4::from_shape_vec((nx, ny, nz, 3), fluence).expect("cells * 3 values"),
            flux,
        }
    }
}

fn deposit_declarations() -> String {
    Consts::new()
        .u32("MAX_SUBPATCHES", MAX_SUBPATCHES as u32)
        .f32("SUBPATCH_SIZE", SUBPATCH_SIZE as f32)
        .f32("SUBPATCH_SLACK", SUBPATCH_SLACK as f32)
        .u32("MAX_PARTS", MAX_PARTS as u32)
        .wgsl()
        .to_string()
}

/// The WGSL of the deposit geometry: [`tube`] (sub-patches, box
/// footprints) and [`Counters::chord`] (the DDA and each piece's amounts),
/// handing the pieces to the kernel's hook `deposit_put`.
pub static WGSL: Module = Module {
    name: "deposit",
    requires: &[&eikon_grid::geometry::WGSL, &crate::patch::WGSL],
    declarations: deposit_declarations,
    text: include_str!("deposit.wgsl"),
};

/// Most sub-patches along one side of a patch (see [`tube`]).
pub const MAX_SUBPATCHES: usize = 8;
/// Sub-patch size, voxels: a patch is cut into sub-patches no larger than
/// this, each deposited with its own footprint.
pub const SUBPATCH_SIZE: f64 = 0.5;

/// Relative slack of [`SUBPATCH_SIZE`]: a patch emitted at a whole number
/// of sub-patches across is cut into that many whatever the rounding of its
/// corners (without it, a patch one voxel across would be cut in two or in
/// three from one step to the next, and the two backends would disagree).
pub const SUBPATCH_SLACK: f64 = 1e-4;

/// Sub-patches along the two sides of a patch whose corners sweep from
/// `x0` to `x1`: enough that none exceeds [`SUBPATCH_SIZE`] voxels on the
/// longer of each pair of opposite edges, before or after the step; `None`
/// where that would take more than [`MAX_SUBPATCHES`] (a patch over four
/// voxels across: see [`tube`]).
#[inline]
pub fn subpatches(x0: &[DVec3; 4], x1: &[DVec3; 4], voxel: f64) -> Option<(usize, usize)> {
    let edge = |p: &[DVec3; 4], a: usize, b: usize| (p[a] - p[b]).length_squared();
    let ls = edge(x0, 1, 0)
        .max(edge(x0, 2, 3))
        .max(edge(x1, 1, 0))
        .max(edge(x1, 2, 3))
        .sqrt();
    let lt = edge(x0, 3, 0)
        .max(edge(x0, 2, 1))
        .max(edge(x1, 3, 0))
        .max(edge(x1, 2, 1))
        .sqrt();
    let count = |l: f64| {
        let k = (l / (SUBPATCH_SIZE * voxel) * (1.0 - SUBPATCH_SLACK))
            .ceil()
            .max(1.0);
        (k <= MAX_SUBPATCHES as f64).then_some(k as usize)
    };
    Some((count(ls)?, count(lt)?))
}

/// Deposit the tube a patch sweeps in one step, corners from `x0` to `x1`
/// (in order around it), carrying `flux` at the start and losing `depth`
/// over the step.
///
/// The patch is cut into `ns x nt` sub-patches ([`subpatches`]), equal
/// cells of its bilinear parameters, each carrying an equal share of the
/// flux: flux is conserved along ray tubes and the patch was uniform in
/// these parameters when emitted, so equal parameter cells carry equal
/// flux wherever the wavefront has since stretched or folded. A sub-patch
/// travels as a straight chord from its centre before the step to its
/// centre after, with a footprint: a box across the two minor axes of the
/// tube's direction of travel with the sub-patch's second moments along
/// them (halfway through the step), cut at the cell faces into up to [`MAX_PARTS`] parts per axis,
/// each part a chord through the centre of its part carrying its share of
/// the box. The parts of a box add up to the whole, so nothing is lost or
/// gained, and a beam along an axis deposits its exact cell overlap; a
/// single line through each patch would alias against the cells. A point
/// focus or a fold needs nothing special: the chords pass through it, and
/// a patch whose orientation flips deposits as before.
///
/// A patch can grow past the split size without being split (its
/// tessellation depth spent, or too dim to be worth it: `refine`). Up to
/// four voxels across, if it is still about a parallelogram, its footprint
/// is cut as above. Beyond that, or when it is far from a parallelogram
/// (typically where it straddles an object's silhouette and its corners
/// part ways), its interior no longer maps its rays and a footprint would
/// smear its light across the gap: its flux then goes along its four
/// corner rays, a quarter each, true rays as photons are.
pub fn tube(
    tally: &Counters,
    x0: &[DVec3; 4],
    x1: &[DVec3; 4],
    flux: &[f64; 3],
    depth: DVec3,
    group: Option<usize>,
) {
    let voxel = tally.grid.voxel_size();
    let torn = |(ns, nt): (usize, usize)| {
        // Over two voxels across and far from a parallelogram: the
        // bilinear interior does not follow the rays (`x0 - x1 + x2 - x3`
        // is zero for a parallelogram).
        let twist = (x1[0] - x1[1] + x1[2] - x1[3]).length();
        ns.max(nt) as f64 * SUBPATCH_SIZE > 2.0 && twist > 0.5 * span(x1)
    };
    let Some((ns, nt)) = subpatches(x0, x1, voxel).filter(|&n| !torn(n)) else {
        let f = flux.map(|x| x * 0.25);
        for c in 0..4 {
            tally.chord(x0[c], x1[c], &f, depth, group);
        }
        return;
    };
    let share = 1.0 / (ns * nt) as f64;
    let at = |p: &[DVec3; 4], s: f64, t: f64| {
        p[0] * ((1.0 - s) * (1.0 - t))
            + p[1] * (s * (1.0 - t))
            + p[2] * (s * t)
            + p[3] * ((1.0 - s) * t)
    };
    let g = &tally.grid;
    let inv = tally.inv_spacing;
    // The axis the tube runs along most (in cells): footprints are boxes
    // in the plane of the other two.
    let run = ((x1[0] + x1[1] + x1[2] + x1[3]) - (x0[0] + x0[1] + x0[2] + x0[3])) * inv;
    let major = if run.x.abs() >= run.y.abs() && run.x.abs() >= run.z.abs() {
        0
    } else if run.y.abs() >= run.z.abs() {
        1
    } else {
        2
    };
    let (ab, ac) = ((major + 1) % 3, (major + 2) % 3);
    let spacing = g.spacing();
    let mut batch = Batched {
        local: Local::new(),
        counters: tally,
        group: group.unwrap_or(0),
    };
    for i in 0..ns {
        let (s0, s1) = (i as f64 / ns as f64, (i + 1) as f64 / ns as f64);
        for j in 0..nt {
            let (t0, t1) = (j as f64 / nt as f64, (j + 1) as f64 / nt as f64);
            let sm = 0.5 * (s0 + s1);
            let tm = 0.5 * (t0 + t1);
            let (a, b) = (at(x0, sm, tm), at(x1, sm, tm));
            // The sub-patch's extent across the two minor axes, halfway
            // through the step, in cells.
            let mid = |s: f64, t: f64| (at(x0, s, t) + at(x1, s, t)) * 0.5;
            let q = [mid(s0, t0), mid(s1, t0), mid(s1, t1), mid(s0, t1)];
            // The box with the sub-patch's second moments: a parallelogram
            // of edges e1, e2 spreads as a box of width sqrt(e1^2 + e2^2)
            // along each axis (exact when it is axis-aligned).
            let (e1, e2) = (
                (q[1] - q[0] + q[2] - q[3]) * 0.5,
                (q[3] - q[0] + q[2] - q[1]) * 0.5,
            );
            let extent = |ax: usize| (e1[ax] * e1[ax] + e2[ax] * e2[ax]).sqrt() * inv[ax];
            let c = (a + b) * 0.5;
            let parts_b = box_parts((c[ab] - g.min[ab]) * inv[ab], extent(ab));
            let parts_c = box_parts((c[ac] - g.min[ac]) * inv[ac], extent(ac));
            for &(fb, ob) in parts_b.iter().take_while(|p| p.0 > 0.0) {
                for &(fc, oc) in parts_c.iter().take_while(|p| p.0 > 0.0) {
                    let mut off = DVec3::ZERO;
                    off[ab] = ob * spacing[ab];
                    off[ac] = oc * spacing[ac];
                    let w = share * fb * fc;
                    let f = flux.map(|x| x * w);
                    tally.chord_with(a + off, b + off, &f, depth, group, &mut batch);
                }
            }
        }
    }
    let group = batch.group;
    batch.local.flush(tally, group);
}

/// Most cells a footprint spans along one axis.
pub const MAX_PARTS: usize = 4;

/// A box footprint of `width` cells centred at cell coordinate `centre`,
/// cut at the cell faces: per part, the fraction of the width it holds and
/// the offset of its centre from `centre` (cells). Unused parts have
/// fraction 0. A footprint wider than [`MAX_PARTS`] cells - 1 is narrowed
/// to that (the caller keeps footprints near a cell).
#[inline]
pub fn box_parts(centre: f64, width: f64) -> [(f64, f64); MAX_PARTS] {
    let mut out = [(0.0, 0.0); MAX_PARTS];
    let w = width.min((MAX_PARTS - 1) as f64);
    if w.is_nan() || w <= 1e-9 || !centre.is_finite() {
        out[0] = (1.0, 0.0);
        return out;
    }
    let (lo, hi) = (centre - 0.5 * w, centre + 0.5 * w);
    let mut x = lo;
    let mut k = 0;
    while x < hi && k < MAX_PARTS {
        let next = (x.floor() + 1.0).min(hi);
        out[k] = ((next - x) / w, 0.5 * (x + next) - centre);
        k += 1;
        x = next;
    }
    out
}

/// Receives the fixed-point amounts of the pieces of chords: the flat
/// index of the cell's first counter, and its fluence and flux-vector
/// amounts (not yet rounded).
trait Put {
    fn put(&mut self, base: usize, fluence: [f64; 3], flux: [f64; 3]);
}

/// Rounds each piece and adds it to the counters at once.
struct Direct<'a> {
    counters: &'a Counters,
    group: usize,
}

impl Put for Direct<'_> {
    #[inline]
    fn put(&mut self, base: usize, fluence: [f64; 3], flux: [f64; 3]) {
        self.counters.add(base, self.group, fluence, flux);
    }
}

impl Counters {
    /// Round `fluence` and `flux` to units and add them to the counters of
    /// the cell whose first counter is `base` (flux-vector array `group`).
    #[inline]
    fn add(&self, base: usize, group: usize, fluence: [f64; 3], flux: [f64; 3]) {
        for (counter, x) in self.fluence[base..base + 3].iter().zip(fluence) {
            // Round to the nearest unit (truncation of a non-negative
            // number, without a libm call).
            let units = (x + 0.5) as u64;
            if units > 0 {
                counter.fetch_add(units, Ordering::Relaxed);
            }
        }
        for (counter, x) in self.flux[group][base..base + 3].iter().zip(flux) {
            let units = x.round() as i64;
            if units != 0 {
                counter.fetch_add(units, Ordering::Relaxed);
            }
        }
    }
}

/// Cells a patch's chords touch in one step, summed before they reach
/// the shared counters: the chords of one patch mostly cross the same
/// few cells, so this saves most of the atomic adds.
struct Local {
    base: [usize; LOCAL_CELLS],
    sums: [[f64; 6]; LOCAL_CELLS],
    len: usize,
}

/// Cells [`Local`] holds before it flushes.
const LOCAL_CELLS: usize = 32;

impl Local {
    fn new() -> Self {
        Self {
            base: [0; LOCAL_CELLS],
            sums: [[0.0; 6]; LOCAL_CELLS],
            len: 0,
        }
    }

    fn flush(&mut self, counters: &Counters, group: usize) {
        for (b, s) in self.base[..self.len].iter().zip(&self.sums[..self.len]) {
            counters.add(*b, group, [s[0], s[1], s[2]], [s[3], s[4], s[5]]);
        }
        self.len = 0;
    }
}

/// A [`Local`] on its way to `counters`.
struct Batched<'a> {
    local: Local,
    counters: &'a Counters,
    group: usize,
}

impl Put for Batched<'_> {
    #[inline]
    fn put(&mut self, base: usize, fluence: [f64; 3], flux: [f64; 3]) {
        let l = &mut self.local;
        let slot = match l.base[..l.len].iter().rposition(|&b| b == base) {
            Some(k) => k,
            None => {
                if l.len == LOCAL_CELLS {
                    l.flush(self.counters, self.group);
                }
                l.base[l.len] = base;
                l.sums[l.len] = [0.0; 6];
                l.len += 1;
                l.len - 1
            }
        };
        let s = &mut l.sums[slot];
        for c in 0..3 {
            s[c] += fluence[c];
            s[3 + c] += flux[c];
        }
    }
}

/// Where one chord's pieces go.
struct Sink {
    /// Fluence units per unit of t.
    w: [f64; 3],
    /// Flux-vector units per unit of t, per channel's share.
    wf: [f64; 3],
    /// The chord's unit direction.
    u: DVec3,
    depth: DVec3,
    dims: [usize; 3],
}

impl Sink {
    /// Hand the piece `[ta, tb]` of the chord in `cell` to `put`.
    #[inline]
    fn add<P: Put>(&self, cell: [i64; 3], ta: f64, tb: f64, put: &mut P) {
        let [i, j, k] = cell.map(|x| x as usize);
        let base = ((i * self.dims[1] + j) * self.dims[2] + k) * 3;
        // int_{ta}^{tb} exp(-tau t) dt per channel: exp(-tau ta) (1 -
        // exp(-tau (tb - ta))) / tau, without the cancellation of the
        // difference when tau is small.
        let mut fluence = [0.0; 3];
        let mut along = 0.0;
        for (c, out) in fluence.iter_mut().enumerate() {
            let tau = self.depth[c];
            let weight = if tau > 0.0 {
                (-tau * ta).exp() * -(-tau * (tb - ta)).exp_m1() / tau
            } else {
                tb - ta
            };
            *out = self.w[c] * weight;
            along += self.wf[c] * weight;
        }
        put.put(base, fluence, (self.u * along).to_array());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Sum of every fluence counter of channel 0, in watt-units of length.
    fn total(t: &Counters) -> f64 {
        t.fluence
            .iter()
            .step_by(3)
            .map(|c| c.load(Ordering::Relaxed) as f64)
            .sum::<f64>()
            / t.scale[0]
    }

    #[test]
    fn a_chord_deposits_its_length_inside_the_volume() {
        let grid = GridGeometry::new([5, 4, 3], DVec3::ZERO, DVec3::new(5.0, 4.0, 3.0));
        let t = Counters::new(&grid, 1, [2.0; 3], 1e9);
        // From outside to outside, obliquely through several cells.
        let (a, b) = (DVec3::new(-1.0, 0.3, 0.2), DVec3::new(6.0, 3.1, 2.9));
        t.chord(a, b, &[2.0, 0.0, 0.0], DVec3::ZERO, None);
        let (t0, t1) = grid.clip_line(a, b - a).unwrap();
        let want = 2.0 * (b - a).length() * (t1.min(1.0) - t0.max(0.0));
        let got = total(&t);
        assert!((got - want).abs() < 1e-7, "{got} vs {want}");
        // The flux vector: the mean of the channels, along the chord.
        let v = t.into_volume();
        let dir = (b - a).normalize();
        let (mut phi, mut f) = (0.0, DVec3::ZERO);
        for i in 0..5 {
            for j in 0..4 {
                for k in 0..3 {
                    phi += v.fluence[[i, j, k, 0]] as f64;
                    f += DVec3::new(
                        v.flux[0][[i, j, k, 0]] as f64,
                        v.flux[0][[i, j, k, 1]] as f64,
                        v.flux[0][[i, j, k, 2]] as f64,
                    );
                }
            }
        }
        assert!((phi - want).abs() < 1e-6 * want, "{phi} vs {want}");
        assert!((f - dir * want / 3.0).length() < 1e-6 * want, "{f}");
    }

    #[test]
    fn an_attenuated_chord_deposits_the_mean_flux() {
        let grid = GridGeometry::new([4, 1, 1], DVec3::ZERO, DVec3::new(4.0, 1.0, 1.0));
        let t = Counters::new(&grid, 1, [1.0; 3], 1e12);
        let tau = 2.0;
        let (a, b) = (DVec3::new(0.0, 0.5, 0.5), DVec3::new(4.0, 0.5, 0.5));
        t.chord(a, b, &[1.0; 3], DVec3::splat(tau), None);
        // Each unit cell gets int exp(-tau x / 4) dx over it.
        let v = t.into_volume();
        for i in 0..4 {
            let x = i as f64;
            let want = 4.0 / tau * ((-tau * x / 4.0).exp() - (-tau * (x + 1.0) / 4.0).exp());
            let got = v.fluence[[i, 0, 0, 1]] as f64;
            assert!((got - want).abs() < 1e-6, "cell {i}: {got} vs {want}");
            let fx = v.flux[0][[i, 0, 0, 0]] as f64;
            assert!((fx - want).abs() < 1e-6, "cell {i}: F {fx} vs {want}");
            assert_eq!(v.flux[0][[i, 0, 0, 1]], 0.0);
        }
    }
}
