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
//! [`volume`](crate::volume) for what the two mean). A photon is such a
//! chord; a patch sweeps a tube, which [`tube`] deposits as its
//! sub-patches' paths with their footprints, the same amounts per piece.
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
        let (w, wf) = self.weights(flux, len, group);
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

    /// What a chord of length `len` carrying `flux` is worth per unit of
    /// its parameter: fluence units per channel, and flux-vector units per
    /// channel's share along its direction (the chord's channel with
    /// dispersion, else the mean of the three channels' vectors).
    #[inline]
    fn weights(&self, flux: &[f64; 3], len: f64, group: Option<usize>) -> ([f64; 3], [f64; 3]) {
        let w = [0, 1, 2].map(|c| flux[c] * len * self.scale[c]);
        let wf = match group {
            Some(g) => {
                let mut wf = [0.0; 3];
                wf[g] = flux[g] * len * self.flux_scale;
                wf
            }
            None => flux.map(|f| f * len * self.flux_scale / 3.0),
        };
        (w, wf)
    }

    /// The edge of a voxel, as [`cut`] measures patches.
    pub fn voxel(&self) -> f64 {
        self.grid.voxel_size()
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
        .u32("SUBPATCHES_PER_SIDE", SUBPATCHES_PER_SIDE as u32)
        .u32("WHOLE_SUBPATCHES", WHOLE_SUBPATCHES as u32)
        .f32("SUBPATCH_SIZE", SUBPATCH_SIZE as f32)
        .f32("SUBPATCH_SLACK", SUBPATCH_SLACK as f32)
        .f32("AXIS_TIE", AXIS_TIE as f32)
        .u32("MAX_PARTS", MAX_PARTS as u32)
        .u32("MAX_SWEPT", MAX_SWEPT as u32)
        .u32("MAX_CUTS", MAX_CUTS as u32)
        .wgsl()
        .to_string()
}

/// The WGSL of the deposit geometry: [`tube`] (sub-patches, layers,
/// swept footprints) and [`Counters::chord`] (the DDA and each piece's
/// amounts), handing the pieces to the kernel's hook `deposit_put`.
pub static WGSL: Module = Module {
    name: "deposit",
    requires: &[&eikon_grid::geometry::WGSL, &crate::patch::WGSL],
    declarations: deposit_declarations,
    text: include_str!("deposit.wgsl"),
};

/// Most sub-patches of [`SUBPATCH_SIZE`] a side of a patch may span for
/// its tube to be deposited with footprints (a patch over four voxels
/// across goes along its corner rays instead: see [`tube`]).
pub const MAX_SUBPATCHES: usize = 8;
/// Sub-patch size, voxels: a patch is cut into sub-patches no larger than
/// this, each deposited with its own footprint, up to
/// [`SUBPATCHES_PER_SIDE`] along a side.
pub const SUBPATCH_SIZE: f64 = 0.5;

/// Most sub-patches along one side of a patch the tessellation left whole
/// ([`left_whole`]) or over two voxels across (a patch it follows is cut
/// into sub-patches of at most [`SUBPATCH_SIZE`]). With the default split
/// size of one voxel, a patch begins a step past it only where the
/// tessellation left it whole: too dim to be worth splitting (the
/// reflected waves), its depth spent, or held while it straddles a
/// surface (`refine`). Its corner rays then lie over a voxel apart and its
/// interior is their bilinear interpolation: cutting it finer resolves
/// that interpolation, not the light, at a cost that grows with its area
/// (the glass sphere's reflected wave spreads over the volume in such
/// patches). A patch the tessellation follows that grows past one voxel
/// within the step keeps the fine cut: halves there raised the point
/// light's error in vacuum (docs/PERFORMANCE.md).
pub const SUBPATCHES_PER_SIDE: usize = 2;

/// Relative slack of [`SUBPATCH_SIZE`]: a patch emitted at a whole number
/// of sub-patches across is cut into that many whatever the rounding of its
/// corners (without it, a patch one voxel across would be cut in two or in
/// three from one step to the next, and the two backends would disagree).
pub const SUBPATCH_SLACK: f64 = 1e-4;

/// The span (world units, the longest edge, [`crate::patch::span`]) over
/// which a patch's [`tube`] surely goes along its four corner rays: a side
/// over [`MAX_SUBPATCHES`] sub-patches long ([`counts`]), on a grid of
/// `voxel` spacing.
pub fn corner_ray_span(voxel: f64) -> f64 {
    MAX_SUBPATCHES as f64 * SUBPATCH_SIZE * voxel / (1.0 - SUBPATCH_SLACK) * (1.0 + 1e-9)
}

/// Sub-patches of [`SUBPATCH_SIZE`] along the two sides of a patch whose
/// corners sweep from `x0` to `x1`: enough that none exceeds
/// [`SUBPATCH_SIZE`] voxels on the longer of each pair of opposite edges,
/// before or after the step (the patch's size in half voxels; [`tube`]
/// cuts a patch over two voxels across into at most
/// [`SUBPATCHES_PER_SIDE`] of them); `None` where that would take more
/// than [`MAX_SUBPATCHES`] (a patch over four voxels across).
#[inline]
pub fn subpatches(x0: &[DVec3; 4], x1: &[DVec3; 4], voxel: f64) -> Option<(usize, usize)> {
    counts(longer(sides2(x0), sides2(x1)), voxel)
}

/// The squared lengths of the longer of each pair of opposite edges of the
/// quad `p`: along `s` (edges 0-1 and 3-2), along `t` (0-3 and 1-2).
#[inline]
fn sides2(p: &[DVec3; 4]) -> (f64, f64) {
    let edge = |a: usize, b: usize| (p[a] - p[b]).length_squared();
    (edge(1, 0).max(edge(2, 3)), edge(3, 0).max(edge(2, 1)))
}

/// The longer of two pairs of sides.
#[inline]
fn longer(a: (f64, f64), b: (f64, f64)) -> (f64, f64) {
    (a.0.max(b.0), a.1.max(b.1))
}

/// Sub-patches of [`SUBPATCH_SIZE`] along sides of squared lengths
/// `(ls2, lt2)` ([`sides2`]); `None` over [`MAX_SUBPATCHES`].
#[inline]
fn counts((ls2, lt2): (f64, f64), voxel: f64) -> Option<(usize, usize)> {
    let count = |l2: f64| {
        let k = (l2.sqrt() / (SUBPATCH_SIZE * voxel) * (1.0 - SUBPATCH_SLACK))
            .ceil()
            .max(1.0);
        (k <= MAX_SUBPATCHES as f64).then_some(k as usize)
    };
    Some((count(ls2)?, count(lt2)?))
}

/// Deposit the tube a patch sweeps along straight corner paths, corners
/// from `x0` to `x1` (in order around it), carrying `flux` at the start
/// and losing `depth` over the way (spread evenly along it): one step, or
/// a run of steps through empty space ([`crate::propagate::Run`]) in one
/// pass.
///
/// The patch is cut into `ns x nt` sub-patches (half a voxel or smaller,
/// [`subpatches`]; over two voxels across or left whole by the
/// tessellation, at most [`SUBPATCHES_PER_SIDE`] along a side), equal cells of its bilinear
/// parameters, each carrying an equal share of the flux: flux is conserved along ray tubes and the patch was uniform in
/// these parameters when emitted, so equal parameter cells carry equal
/// flux wherever the wavefront has since stretched or folded. A sub-patch's
/// centre moves along a line from before to after, and its edges change
/// linearly (the corners do). The tube is followed layer by layer of cells
/// along its major axis, and within a layer each sub-patch's path is cut
/// where its centre crosses a face of the two minor axes. Over each piece
/// the sub-patch deposits a footprint across the minor axes: a box with
/// its second moments at the piece's middle (a parallelogram of edges
/// `e1`, `e2` spreads as a box of width `sqrt(e1^2 + e2^2)` along each
/// axis, exact when it is axis-aligned), swept along with the centre over
/// the piece, whose integral over each cell is exact ([`swept_parts`]).
/// The footprint's parts add up to the whole, so nothing is lost or
/// gained; a thin beam deposits its exact chord, and a beam along an axis
/// its exact cell overlap. A point focus or a fold needs nothing special:
/// the paths pass through it, and a patch whose orientation flips deposits
/// as before.
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
    let n = cut(x0, x1, tally.voxel());
    tube_cut(tally, (x0, x1), flux, &[1.0; 4], depth, group, n);
}

/// [`tube`] cut into `n` sub-patches (`ns x nt`), or along its four corner
/// rays where `n` is `None` (as [`cut`] finds, or as the other piece of a
/// path bent within a step asks, `propagate::bent_tube`), for a patch
/// whose light need not be uniform over it: the flux per unit of its
/// bilinear parameters is `flux` times the bilinear interpolation of
/// `weights` (one per corner), each sub-patch's share taken at its centre,
/// a corner ray's at its corner. A patch that straddles a surface carries
/// on beyond it only what the surface let through
/// (`propagate::straddle_weights`).
pub fn tube_cut(
    tally: &Counters,
    (x0, x1): (&[DVec3; 4], &[DVec3; 4]),
    flux: &[f64; 3],
    weights: &[f64; 4],
    depth: DVec3,
    group: Option<usize>,
    n: Option<(usize, usize)>,
) {
    let Some(n) = n else {
        for c in 0..4 {
            let f = flux.map(|x| x * 0.25 * weights[c]);
            tally.chord(x0[c], x1[c], &f, depth, group);
        }
        return;
    };
    LANES.with_borrow_mut(|(lanes, tile)| {
        let tube = Tube {
            tally,
            x0,
            x1,
            flux,
            weights,
            depth,
            group,
            axes: axes(x0, x1, tally.inv_spacing),
        };
        tube.lanes(n, lanes);
        tube.deposit(lanes, tile);
    });
}

/// How [`tube`] cuts the patch whose corners sweep from `x0` to `x1`:
/// into `ns x nt` sub-patches ([`subpatches`], at most
/// [`SUBPATCHES_PER_SIDE`] along a side where it is over two voxels
/// across or [`left_whole`]), or `None` where it goes along its four
/// corner rays (over [`MAX_SUBPATCHES`], or [`torn`]).
#[inline]
pub fn cut(x0: &[DVec3; 4], x1: &[DVec3; 4], voxel: f64) -> Option<(usize, usize)> {
    let start = sides2(x0);
    let (ns, nt) = counts(longer(start, sides2(x1)), voxel).filter(|&n| !torn(x1, n))?;
    Some(if wide((ns, nt)) || left_whole(start, voxel) {
        (ns.min(SUBPATCHES_PER_SIDE), nt.min(SUBPATCHES_PER_SIDE))
    } else {
        (ns, nt)
    })
}

/// Whether a patch cut into `ns x nt` sub-patches that ends a step at `x1`
/// is torn: over two voxels across and far from a parallelogram, so that
/// its bilinear interior does not follow the rays (`x0 - x1 + x2 - x3` is
/// zero for a parallelogram).
#[inline]
fn torn(x1: &[DVec3; 4], n: (usize, usize)) -> bool {
    let twist = (x1[0] - x1[1] + x1[2] - x1[3]).length();
    wide(n) && twist > 0.5 * span(x1)
}

/// Whether a patch of `ns x nt` sub-patches of [`SUBPATCH_SIZE`] is over
/// two voxels across.
#[inline]
fn wide((ns, nt): (usize, usize)) -> bool {
    ns.max(nt) as f64 * SUBPATCH_SIZE > 2.0
}

/// Whether a patch whose sides are `start` ([`sides2`]) when a step
/// begins was left whole by the tessellation: over one voxel (the default
/// split size) along a side before the step. A patch the tessellation follows begins every step
/// (or run of steps) at most the split size across, as `refine` left it;
/// one already past it is too dim to be worth splitting, held while it
/// straddles a surface, or its depth is spent, and its corner rays lie
/// over a voxel apart (its interior is their interpolation).
#[inline]
fn left_whole(start: (f64, f64), voxel: f64) -> bool {
    counts(start, voxel).is_none_or(|(s, t)| s.max(t) > WHOLE_SUBPATCHES)
}

/// Sub-patches of [`SUBPATCH_SIZE`] along a side of a patch one voxel
/// across ([`left_whole`]).
pub const WHOLE_SUBPATCHES: usize = (1.0 / SUBPATCH_SIZE) as usize;

/// The point of a patch at bilinear parameters `(s, t)`.
#[inline]
fn bilinear(p: &[DVec3; 4], s: f64, t: f64) -> DVec3 {
    p[0] * ((1.0 - s) * (1.0 - t))
        + p[1] * (s * (1.0 - t))
        + p[2] * (s * t)
        + p[3] * ((1.0 - s) * t)
}

/// The bilinear interpolation of per-corner `weights` at `(s, t)`; the
/// weight itself, exactly, where all four are equal. The GPU's
/// `deposit_weight_at`.
#[inline]
pub fn weight_at(w: &[f64; 4], s: f64, t: f64) -> f64 {
    if w[1] == w[0] && w[2] == w[0] && w[3] == w[0] {
        return w[0];
    }
    w[0] * ((1.0 - s) * (1.0 - t))
        + w[1] * (s * (1.0 - t))
        + w[2] * (s * t)
        + w[3] * ((1.0 - s) * t)
}

/// The two edge vectors of the parallelogram nearest a quad `q`.
#[inline]
fn edges(q: &[DVec3; 4]) -> (DVec3, DVec3) {
    (
        (q[1] - q[0] + q[2] - q[3]) * 0.5,
        (q[3] - q[0] + q[2] - q[1]) * 0.5,
    )
}

/// How near two axes' runs must be for [`axes`] to take them as tied, and
/// the first: the tubes of one wave must all be cut along the same axis,
/// since their footprints in a layer only add up evenly with their
/// neighbours' in the same layers, and a wave at 45 degrees to two axes
/// would otherwise pick either by the rounding of its corners (on the GPU
/// in f32).
pub const AXIS_TIE: f64 = 1e-4;

/// The axis a tube from `x0` to `x1` runs along most, in cells, first
/// (footprints lie across the other two), then those two.
#[inline]
fn axes(x0: &[DVec3; 4], x1: &[DVec3; 4], inv: DVec3) -> [usize; 3] {
    let run = ((x1[0] + x1[1] + x1[2] + x1[3]) - (x0[0] + x0[1] + x0[2] + x0[3])) * inv;
    let r = run.abs();
    let tie = 1.0 - AXIS_TIE;
    let major = if r.x >= r.y * tie && r.x >= r.z * tie {
        0
    } else if r.y >= r.z * tie {
        1
    } else {
        2
    };
    [major, (major + 1) % 3, (major + 2) % 3]
}

thread_local! {
    /// [`tube`]'s sub-patches and its layer's cells, kept for the thread's
    /// life (no allocation or clearing per tube).
    static LANES: std::cell::RefCell<(Vec<Lane>, Box<Tile>)> =
        std::cell::RefCell::new((Vec::new(), Box::new(Tile::new())));
}

/// One [`tube`] being deposited.
struct Tube<'a> {
    tally: &'a Counters,
    x0: &'a [DVec3; 4],
    x1: &'a [DVec3; 4],
    flux: &'a [f64; 3],
    /// Per corner, the weight of the flux ([`tube_cut`]).
    weights: &'a [f64; 4],
    depth: DVec3,
    group: Option<usize>,
    /// Its major axis, then the two minor ones ([`axes`]).
    axes: [usize; 3],
}

/// One sub-patch of a [`tube`], in cell coordinates along the tube's axes
/// (major, then the two minor ones, [`axes`]): its centre at the start and
/// how far it moves, the two minor components of its edges at the start
/// and of how they change (projected along its motion onto the layers'
/// plane, [`onto_layer`]), the part of its path inside the grid along the
/// major axis, and what it deposits per unit of the tube's parameter
/// (fluence units per channel, flux-vector units per channel along `u`,
/// in world axes). Held in the tube's axis order, so the walk over layers
/// indexes no vector by a runtime axis.
#[derive(Clone, Copy)]
struct Lane {
    at: [f64; 3],
    moves: [f64; 3],
    e1: [f64; 2],
    de1: [f64; 2],
    e2: [f64; 2],
    de2: [f64; 2],
    lo: f64,
    hi: f64,
    fluence: [f64; 3],
    flux: [f64; 3],
    u: DVec3,
}

impl Tube<'_> {
    /// The `ns x nt` sub-patches, into `lanes`.
    fn lanes(&self, (ns, nt): (usize, usize), lanes: &mut Vec<Lane>) {
        let &Tube { tally, x0, x1, .. } = self;
        let g = &tally.grid;
        let inv = tally.inv_spacing;
        let m = self.axes[0];
        let dims_m = g.dims[m] as f64;
        let share = self.flux.map(|f| f / (ns * nt) as f64);
        let cell = |p: DVec3| (p - g.min) * inv;
        lanes.clear();
        for i in 0..ns {
            let (s0, s1) = (i as f64 / ns as f64, (i + 1) as f64 / ns as f64);
            for j in 0..nt {
                let (t0, t1) = (j as f64 / nt as f64, (j + 1) as f64 / nt as f64);
                let (sm, tm) = (0.5 * (s0 + s1), 0.5 * (t0 + t1));
                let (a, b) = (bilinear(x0, sm, tm), bilinear(x1, sm, tm));
                let len = (b - a).length();
                if !(len > 0.0 && len.is_finite()) {
                    continue;
                }
                let quad = |p: &[DVec3; 4]| {
                    [
                        bilinear(p, s0, t0),
                        bilinear(p, s1, t0),
                        bilinear(p, s1, t1),
                        bilinear(p, s0, t1),
                    ]
                };
                let (e1, e2) = edges(&quad(x0));
                let (f1, f2) = edges(&quad(x1));
                let (at, moves) = (cell(a), (b - a) * inv);
                // The part of the centre's path inside the grid along the
                // major axis (the minor axes are clipped cell by cell).
                let (lo, hi) = if moves[m] != 0.0 {
                    let (ta, tb) = (-at[m] / moves[m], (dims_m - at[m]) / moves[m]);
                    (ta.min(tb).max(0.0), ta.max(tb).min(1.0))
                } else if at[m] >= 0.0 && at[m] < dims_m {
                    (0.0, 1.0)
                } else {
                    continue;
                };
                if hi.is_nan() || hi <= lo {
                    continue;
                }
                let w = weight_at(self.weights, sm, tm);
                let (fluence, flux) = tally.weights(&share.map(|f| f * w), len, self.group);
                let [_, ab, ac] = self.axes;
                let minor = |e: DVec3| {
                    let p = onto_layer(e * inv, moves, m);
                    [p[ab], p[ac]]
                };
                let in_axes = |v: DVec3| self.axes.map(|a| v[a]);
                lanes.push(Lane {
                    at: in_axes(at),
                    moves: in_axes(moves),
                    e1: minor(e1),
                    de1: minor(f1 - e1),
                    e2: minor(e2),
                    de2: minor(f2 - e2),
                    lo,
                    hi,
                    fluence,
                    flux,
                    u: (b - a) / len,
                });
            }
        }
    }

    /// Deposit `lanes` layer by layer along the major axis: a layer's cells
    /// are summed over every sub-patch before they reach the counters.
    fn deposit(&self, lanes: &[Lane], tile: &mut Tile) {
        let &Tube {
            tally, depth, axes, ..
        } = self;
        let g = &tally.grid;
        let m = axes[0];
        let top = g.dims[m] as i64 - 1;
        let layer = |l: &Lane, t: f64| (floor(l.at[0] + l.moves[0] * t) as i64).clamp(0, top);
        let (first, last) = lanes.iter().fold((i64::MAX, i64::MIN), |(a, b), l| {
            let (p, q) = (layer(l, l.lo), layer(l, l.hi));
            (a.min(p).min(q), b.max(p).max(q))
        });
        let group = self.group.unwrap_or(0);
        let cells = Cells::new(g, axes);
        for layer in first..=last {
            let layer_base = layer as usize * cells.stride[0];
            for lane in lanes {
                let Some((ta, tb)) = lane.in_layer(layer) else {
                    continue;
                };
                // Cut where the centre crosses a face of the two minor
                // axes: within each piece it stays in one cell.
                let mut cuts = [0.0; 2 + 2 * MAX_CUTS];
                let mut n = 1;
                cuts[0] = ta;
                for ax in [1, 2] {
                    let ya = lane.at[ax] + lane.moves[ax] * ta;
                    let yb = lane.at[ax] + lane.moves[ax] * tb;
                    let (lo, hi) = (ya.min(yb), ya.max(yb));
                    let mut face = floor(lo) + 1.0;
                    let end = n + MAX_CUTS;
                    while face < hi && n < end {
                        cuts[n] = ((face - lane.at[ax]) / lane.moves[ax]).clamp(ta, tb);
                        n += 1;
                        face += 1.0;
                    }
                }
                cuts[n] = tb;
                n += 1;
                // The inner cuts in order (at most `2 MAX_CUTS` of them: an
                // insertion sort, as the GPU's).
                for p in 2..n - 1 {
                    let v = cuts[p];
                    let mut q = p;
                    while q > 1 && cuts[q - 1] > v {
                        cuts[q] = cuts[q - 1];
                        q -= 1;
                    }
                    cuts[q] = v;
                }
                for piece in cuts[..n].windows(2) {
                    lane.deposit(piece[0], piece[1], depth, &cells, layer_base, tile);
                }
            }
            // A layer's cells are not met again.
            tile.flush(tally, group);
        }
    }
}

/// Most faces of one minor axis a [`tube`]'s sub-patch centre crosses
/// within one layer that are cut at (a sub-patch steeper than that is cut
/// at the first of them; its sweep covers the rest).
pub const MAX_CUTS: usize = 4;

impl Lane {
    /// The part `[ta, tb]` of the tube's parameter in layer `layer` of
    /// the major axis, if any.
    #[inline]
    fn in_layer(&self, layer: i64) -> Option<(f64, f64)> {
        let (g, d) = (self.at[0], self.moves[0]);
        let (l0, l1) = (layer as f64, (layer + 1) as f64);
        let (ta, tb) = if d > 0.0 {
            (((l0 - g) / d).max(self.lo), ((l1 - g) / d).min(self.hi))
        } else if d < 0.0 {
            (((l1 - g) / d).max(self.lo), ((l0 - g) / d).min(self.hi))
        } else if floor(g) as i64 == layer {
            (self.lo, self.hi)
        } else {
            return None;
        };
        (tb > ta).then_some((ta, tb))
    }

    /// Deposit the piece `[ta, tb]` of the lane in the layer of the major
    /// axis whose first counter is `layer_base`, losing `depth` over the
    /// whole tube: across each minor axis the sub-patch's box footprint,
    /// with its second moments at the piece's middle, swept along with the
    /// centre over the piece ([`swept_parts`]).
    #[inline]
    fn deposit(
        &self,
        ta: f64,
        tb: f64,
        depth: DVec3,
        cells: &Cells,
        layer_base: usize,
        tile: &mut Tile,
    ) {
        let dt = tb - ta;
        if dt <= 0.0 {
            return;
        }
        let t = 0.5 * (ta + tb);
        let c = |k: usize| self.at[k] + self.moves[k] * t;
        let edge = |e: [f64; 2], de: [f64; 2], k: usize| e[k] + de[k] * t;
        let width = |k: usize| {
            let (e1, e2) = (edge(self.e1, self.de1, k), edge(self.e2, self.de2, k));
            (e1 * e1 + e2 * e2).sqrt()
        };
        let weight = attenuated(depth, ta, tb);
        let fluence: [f64; 3] = std::array::from_fn(|ch| self.fluence[ch] * weight[ch]);
        let along = self.u * (0..3).map(|ch| self.flux[ch] * weight[ch]).sum::<f64>();
        let pb = swept_parts(c(1), width(0), (self.moves[1] * dt).abs());
        let pc = swept_parts(c(2), width(1), (self.moves[2] * dt).abs());
        // The parts inside the grid (the rest leave it).
        let (bs, cs) = (cells.inside(&pb, 1), cells.inside(&pc, 2));
        for (&fb, ib) in pb.fraction[bs.clone()]
            .iter()
            .zip(pb.first + bs.start as i64..)
        {
            let row = layer_base + ib as usize * cells.stride[1];
            for (&fc, ic) in pc.fraction[cs.clone()]
                .iter()
                .zip(pc.first + cs.start as i64..)
            {
                let f = fb * fc;
                tile.put(
                    [ib, ic],
                    row + ic as usize * cells.stride[2],
                    fluence.map(|w| w * f),
                    (along * f).to_array(),
                );
            }
        }
    }
}

/// A sub-patch's edge `e` (cell coordinates) as its footprint in a layer
/// of the major axis `m` has it, for a sub-patch moving along `moves`: `e`
/// projected along the motion onto the layer's plane (the cross-section of
/// its tube there, which the piece then sweeps across the layer). Projected
/// straight onto the plane instead (the patch as it stands), a tube that
/// crosses the layers at `theta` to the axis would be `cos^2 theta` too
/// narrow, and the footprints of neighbouring tubes would no longer add up
/// evenly: a plane wave at 40 degrees to the axis read up to 4% high and
/// low from cell to cell, at 45 degrees up to 9%. A motion nearly along
/// the layer (below a quarter of its largest component) keeps the straight
/// projection, whose cross-section would be unbounded (wide footprints are
/// narrowed to [`MAX_PARTS`] - 1 cells in any case). The projection is
/// linear and the motion is the lane's own, so a lane's edges and their
/// change over the step are projected once. The GPU's
/// `deposit_onto_layer`.
#[inline]
pub fn onto_layer(e: DVec3, moves: DVec3, m: usize) -> DVec3 {
    if moves[m].abs() >= 0.25 * moves.abs().max_element() && moves[m] != 0.0 {
        e - moves * (e[m] / moves[m])
    } else {
        e
    }
}

/// The grid's cells as a [`tube`] walks them: along each of its axes
/// (major, then the two minor ones, [`axes`]), the cells and the counters
/// between neighbours (the flat index of cell `(i, j, k)`'s first counter
/// is `((i ny + j) nz + k) 3`).
struct Cells {
    dims: [i64; 3],
    stride: [usize; 3],
}

impl Cells {
    fn new(g: &GridGeometry, axes: [usize; 3]) -> Self {
        let d = g.dims;
        let flat = [d[1] * d[2] * 3, d[2] * 3, 3];
        Self {
            dims: axes.map(|a| d[a] as i64),
            stride: axes.map(|a| flat[a]),
        }
    }

    /// Which of the swept parts `p` along the `k`-th of [`Self::axes`]
    /// lie inside the grid (saturating: a footprint's first cell is
    /// `i64::MIN` or `MAX` for a centre beyond the `i64` range).
    #[inline]
    fn inside(&self, p: &SweptParts, k: usize) -> std::ops::Range<usize> {
        let n = p.count as i64;
        let lo = 0i64.saturating_sub(p.first).clamp(0, n);
        let hi = self.dims[k].saturating_sub(p.first).clamp(lo, n);
        lo as usize..hi as usize
    }
}

/// `int_{ta}^{tb} exp(-tau t) dt` per channel of the optical depth `depth`
/// over the whole chord: `exp(-tau ta) (1 - exp(-tau (tb - ta))) / tau`,
/// without the cancellation of the difference when `tau` is small.
#[inline]
fn attenuated(depth: DVec3, ta: f64, tb: f64) -> [f64; 3] {
    let one = |tau: f64| {
        if tau > 0.0 {
            (-tau * ta).exp() * -(-tau * (tb - ta)).exp_m1() / tau
        } else {
            tb - ta
        }
    };
    // Channels of one extinction (grey media, or two alike) share the
    // exponentials.
    let r = one(depth.x);
    let g = if depth.y == depth.x { r } else { one(depth.y) };
    let b = if depth.z == depth.y {
        g
    } else if depth.z == depth.x {
        r
    } else {
        one(depth.z)
    };
    [r, g, b]
}

/// Most cells a swept footprint spans along one axis ([`swept_parts`]).
pub const MAX_SWEPT: usize = MAX_PARTS + 2;

/// The cells a swept footprint covers along one axis ([`swept_parts`]):
/// `count` cells from `first` on, holding `fraction[k]` of its mass.
#[derive(Clone, Copy, Debug)]
pub struct SweptParts {
    /// The first cell.
    pub first: i64,
    /// How many cells.
    pub count: usize,
    /// The fraction each holds.
    pub fraction: [f64; MAX_SWEPT],
}

/// A box footprint of `width` cells whose centre moves uniformly over
/// `sweep` cells, centred at cell coordinate `centre`: the cells it covers
/// and the fraction of its time-integrated mass each holds. The mass is the
/// convolution of two boxes, a trapezoid, whose integral over a cell is
/// exact (the distribution function is piecewise quadratic). A footprint
/// wider than [`MAX_PARTS`] - 1 cells is narrowed to that, and a sweep to
/// two cells.
#[inline(always)]
pub fn swept_parts(centre: f64, width: f64, sweep: f64) -> SweptParts {
    let mut out = SweptParts {
        first: 0,
        count: 1,
        fraction: [0.0; MAX_SWEPT],
    };
    out.fraction[0] = 1.0;
    if !centre.is_finite() {
        return out;
    }
    let w = if width.is_nan() {
        0.0
    } else {
        width.min((MAX_PARTS - 1) as f64)
    };
    let s = if sweep.is_nan() { 0.0 } else { sweep.min(2.0) };
    let (a, b) = (w.min(s), w.max(s));
    let half = 0.5 * (a + b);
    let first = floor(centre - half);
    out.first = first as i64;
    if b <= 1e-9 || centre + half <= first + 1.0 {
        // Within one cell.
        return out;
    }
    // The distribution function of U(-a/2, a/2) + U(-b/2, b/2) at x: a
    // ramp up over a, flat over b - a, a ramp down over a.
    let inner = 0.5 * (b - a);
    let ramp = if a > 1e-9 * b { 0.5 / (a * b) } else { 0.0 };
    let cdf = |x: f64| {
        if x <= -inner {
            (x + half) * (x + half) * ramp
        } else if x <= inner {
            (x + inner) / b + 0.5 * a / b
        } else {
            1.0 - (half - x) * (half - x) * ramp
        }
    };
    let end = centre + half;
    let mut below = 0.0;
    let mut k = 0;
    while k < MAX_SWEPT {
        let face = first + (k + 1) as f64;
        if face >= end {
            out.fraction[k] = 1.0 - below;
            k += 1;
            break;
        }
        let upto = cdf(face - centre);
        out.fraction[k] = upto - below;
        below = upto;
        k += 1;
    }
    out.count = k;
    out
}

/// `x.floor()` for the cell coordinates of the deposit, without a libm
/// call (the baseline x86-64 has no rounding instruction) or a conversion
/// to an integer: adding and taking away `1.5 * 2^52` rounds to the
/// nearest integer; exact for `|x| < 2^51`, and far outside the grid
/// beyond that (NaN stays NaN).
#[inline(always)]
fn floor(x: f64) -> f64 {
    const ROUND: f64 = 6_755_399_441_055_744.0;
    let t = (x + ROUND) - ROUND;
    if t > x {
        t - 1.0
    } else {
        t
    }
}

/// A footprint is at most `MAX_PARTS - 1` cells wide along one axis
/// ([`swept_parts`] narrows a wider one; patches that wide are deposited
/// along their corner rays, [`tube`]).
pub const MAX_PARTS: usize = 4;

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
            // number, without a libm call). Through `i64`, which x86-64
            // converts in one instruction (`u64` takes a branchy sequence):
            // the same units below 2^63, far beyond what one call adds (a
            // cell's share of one layer of a tube, or of one chord's piece:
            // [`crate::units_per_crossing`] units per voxel crossed at the
            // brightest flux).
            let units = (x + 0.5) as i64;
            if units > 0 {
                counter.fetch_add(units as u64, Ordering::Relaxed);
            }
        }
        for (counter, x) in self.flux[group][base..base + 3].iter().zip(flux) {
            // To the nearest unit, halves away from zero (as `round`, without
            // its libm call).
            let units = if x >= 0.0 {
                (x + 0.5) as i64
            } else {
                -((0.5 - x) as i64)
            };
            if units != 0 {
                counter.fetch_add(units, Ordering::Relaxed);
            }
        }
    }
}

/// The cells one layer of a [`tube`] touches, summed over its sub-patches
/// before they reach the shared counters (a cell is met by several
/// sub-patches and pieces, so this saves most of the atomic adds): a
/// square of [`TILE`] x [`TILE`] cells of the two minor axes, placed
/// around the layer's first cell, indexed directly, and for the rare cell
/// outside it a short list. Each cell is flushed once per layer, in the
/// order it was first met (deterministic).
struct Tile {
    /// The tile's first cell along the two minor axes, once placed.
    origin: Option<[i64; 2]>,
    /// Per tile cell, the flat index of its first counter; `usize::MAX`
    /// where not met in this layer.
    base: [usize; TILE * TILE],
    /// Per tile cell, its fluence and flux-vector sums.
    sums: [[f64; 6]; TILE * TILE],
    /// The tile cells met, in order.
    met: [u16; TILE * TILE],
    len: usize,
    /// Cells outside the tile: their first counters and sums.
    spill: Vec<(usize, [f64; 6])>,
}

/// Cells along each side of a [`Tile`].
const TILE: usize = 16;

impl Tile {
    fn new() -> Self {
        Self {
            origin: None,
            base: [usize::MAX; TILE * TILE],
            sums: [[0.0; 6]; TILE * TILE],
            met: [0; TILE * TILE],
            len: 0,
            spill: Vec::new(),
        }
    }

    /// Add the amounts of the cell at minor-axis cells `at`, whose first
    /// counter is `base`.
    #[inline]
    fn put(&mut self, at: [i64; 2], base: usize, fluence: [f64; 3], flux: [f64; 3]) {
        let half = (TILE / 2) as i64;
        let o = *self.origin.get_or_insert([at[0] - half, at[1] - half]);
        let (db, dc) = ((at[0] - o[0]) as u64, (at[1] - o[1]) as u64);
        let s = if db < TILE as u64 && dc < TILE as u64 {
            let k = db as usize * TILE + dc as usize;
            if self.base[k] == usize::MAX {
                self.base[k] = base;
                self.sums[k] = [0.0; 6];
                self.met[self.len] = k as u16;
                self.len += 1;
            }
            &mut self.sums[k]
        } else {
            let k = match self.spill.iter().position(|&(b, _)| b == base) {
                Some(k) => k,
                None => {
                    self.spill.push((base, [0.0; 6]));
                    self.spill.len() - 1
                }
            };
            &mut self.spill[k].1
        };
        for c in 0..3 {
            s[c] += fluence[c];
            s[3 + c] += flux[c];
        }
    }

    /// Round the layer's sums to units, add them to `counters` (flux-vector
    /// array `group`) and empty the tile for the next layer.
    fn flush(&mut self, counters: &Counters, group: usize) {
        for &k in &self.met[..self.len] {
            let k = k as usize;
            let s = &self.sums[k];
            counters.add(self.base[k], group, [s[0], s[1], s[2]], [s[3], s[4], s[5]]);
            self.base[k] = usize::MAX;
        }
        for (b, s) in self.spill.drain(..) {
            counters.add(b, group, [s[0], s[1], s[2]], [s[3], s[4], s[5]]);
        }
        self.len = 0;
        self.origin = None;
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
        let weight = attenuated(self.depth, ta, tb);
        let fluence: [f64; 3] = std::array::from_fn(|c| self.w[c] * weight[c]);
        let along = (0..3).map(|c| self.wf[c] * weight[c]).sum::<f64>();
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

    /// A square patch of side `side` centred at `c` across the axis `n`
    /// (unit), its corners in order around it.
    fn square(c: DVec3, n: DVec3, side: f64) -> [DVec3; 4] {
        let u = n.any_orthonormal_vector();
        let v = n.cross(u);
        let h = 0.5 * side;
        [
            c - u * h - v * h,
            c + u * h - v * h,
            c + u * h + v * h,
            c - u * h + v * h,
        ]
    }

    #[test]
    fn a_patch_the_tessellation_left_whole_is_cut_coarser() {
        let voxel = 0.1;
        let sq = |side: f64, z: f64| square(DVec3::new(0.0, 0.0, z), DVec3::Z, side * voxel);
        // Sub-patches of at most half a voxel over the step, while the
        // patch began it at most one voxel across (as `refine` leaves a
        // patch it follows).
        assert_eq!(cut(&sq(0.4, 0.0), &sq(0.45, 0.1), voxel), Some((1, 1)));
        assert_eq!(cut(&sq(1.0, 0.0), &sq(1.0, 0.1), voxel), Some((2, 2)));
        assert_eq!(cut(&sq(0.9, 0.0), &sq(1.4, 0.1), voxel), Some((3, 3)));
        assert_eq!(cut(&sq(0.9, 0.0), &sq(1.9, 0.1), voxel), Some((4, 4)));
        // Over a voxel before the step: left whole, in halves.
        assert_eq!(cut(&sq(1.2, 0.0), &sq(1.4, 0.1), voxel), Some((2, 2)));
        assert_eq!(cut(&sq(1.9, 0.0), &sq(1.6, 0.1), voxel), Some((2, 2)));
        // Over two voxels after it, in halves; over four, along its corners.
        assert_eq!(cut(&sq(0.9, 0.0), &sq(2.6, 0.1), voxel), Some((2, 2)));
        assert_eq!(cut(&sq(0.9, 0.0), &sq(4.2, 0.1), voxel), None);
    }

    /// The length of the segment `a`-`b` in each unit cell of a grid from
    /// the origin, found independently of the deposit: every parameter
    /// where it crosses a cell face, sorted, each interval given to the
    /// cell of its middle.
    fn chord_lengths(dims: [usize; 3], a: DVec3, b: DVec3) -> Vec<([usize; 3], f64)> {
        let d = b - a;
        let mut ts = vec![0.0, 1.0];
        for ax in 0..3 {
            for face in 0..=dims[ax] {
                let t = (face as f64 - a[ax]) / d[ax];
                if t > 0.0 && t < 1.0 {
                    ts.push(t);
                }
            }
        }
        ts.sort_by(f64::total_cmp);
        let mut out = Vec::new();
        for w in ts.windows(2) {
            let p = a + d * (0.5 * (w[0] + w[1]));
            let cell = [0, 1, 2].map(|ax| p[ax].floor() as usize);
            out.push((cell, d.length() * (w[1] - w[0])));
        }
        out
    }

    #[test]
    fn a_thin_tube_deposits_its_exact_chord() {
        // A patch a thousandth of a voxel across, obliquely through many
        // cells: each cell gets the flux times the length of the centre
        // line inside it.
        let dims = [9, 8, 7];
        let grid = GridGeometry::new(dims, DVec3::ZERO, DVec3::new(9.0, 8.0, 7.0));
        let t = Counters::new(&grid, 1, [1.0; 3], 1e12);
        let (a, b) = (DVec3::new(0.3, 7.6, 0.45), DVec3::new(8.7, 0.2, 6.1));
        let dir = (b - a).normalize();
        let x0 = square(a, dir, 1e-3);
        let x1 = x0.map(|x| x + (b - a));
        tube(&t, &x0, &x1, &[1.0; 3], DVec3::ZERO, None);
        let v = t.into_volume();
        let want = chord_lengths(dims, a, b);
        assert!(want.len() > 20, "{} cells", want.len());
        let mut seen = 0.0;
        for (c, len) in want {
            let got = v.fluence[[c[0], c[1], c[2], 0]] as f64;
            assert!(
                (got - len).abs() < 2e-3 * len + 1e-9,
                "cell {c:?}: {got} vs {len}"
            );
            seen += got;
        }
        let all: f64 = v.fluence.iter().step_by(3).map(|&x| x as f64).sum();
        // Nothing outside the chord's cells (the volume holds f32).
        assert!((all - seen).abs() < 1e-6 * all, "{all} vs {seen}");
    }

    #[test]
    fn an_axis_aligned_beam_deposits_its_exact_cell_overlap() {
        // A square patch 1.7 voxels wide travelling 4.5 voxels along z:
        // each cell gets the flux per area times its overlap with the
        // square times the length inside it.
        let dims = [6, 6, 8];
        let grid = GridGeometry::new(dims, DVec3::ZERO, DVec3::new(6.0, 6.0, 8.0));
        let t = Counters::new(&grid, 1, [1.0; 3], 1e12);
        let (lo, side) = (DVec3::new(1.8, 2.35, 1.25), 1.7);
        let x0 = [
            lo,
            lo + DVec3::X * side,
            lo + DVec3::new(side, side, 0.0),
            lo + DVec3::Y * side,
        ];
        let run = DVec3::Z * 4.5;
        let x1 = x0.map(|x| x + run);
        let flux = 2.0;
        tube(&t, &x0, &x1, &[flux; 3], DVec3::ZERO, None);
        let v = t.into_volume();
        let overlap =
            |c: usize, lo: f64, hi: f64| (hi.min(c as f64 + 1.0) - lo.max(c as f64)).max(0.0);
        for i in 0..6 {
            for j in 0..6 {
                for k in 0..8 {
                    let area = overlap(i, lo.x, lo.x + side) * overlap(j, lo.y, lo.y + side);
                    let want = flux / (side * side) * area * overlap(k, lo.z, lo.z + 4.5);
                    let got = v.fluence[[i, j, k, 0]] as f64;
                    // To the volume's f32.
                    assert!(
                        (got - want).abs() < 1e-6 * flux,
                        "cell ({i}, {j}, {k}): {got} vs {want}"
                    );
                }
            }
        }
    }

    /// [`corner_ray_span`] is where [`tube`] surely goes along the corner
    /// rays: a patch whose longest edge is over it when a step begins is
    /// never cut into sub-patches, whatever it does in the step, and one
    /// just under it with all edges so before and after the step is.
    #[test]
    fn over_the_corner_ray_span_a_tube_goes_along_its_corner_rays() {
        let voxel = 0.1;
        let wide = corner_ray_span(voxel);
        let mut rng = eikon_rng::SplitMix64::new(29);
        let mut u = || rng.unit();
        let mut rv = || DVec3::new(u(), u(), u()) - 0.5;
        for _ in 0..5000 {
            let (a, b) = (rv().normalize(), rv().normalize());
            let side = |f: f64| [DVec3::ZERO, a * f, a * f + b * f, b * f];
            let over = side(wide * (1.0 + 1e-7));
            assert!(span(&over) > wide);
            let moved = over.map(|x| x + rv() * voxel);
            assert_eq!(cut(&over, &moved, voxel), None);
            // A parallelogram just within the span, moved rigidly.
            let within = side(wide * 0.999);
            let shift = rv() * voxel;
            let moved = within.map(|x| x + shift);
            assert!(cut(&within, &moved, voxel).is_some());
        }
    }

    #[test]
    fn a_tube_deposits_its_flux_times_length_less_what_it_loses() {
        // A tilted, slightly sheared patch translated obliquely, inside the
        // grid: every sub-patch travels the same length, so the fluence
        // sums to the flux times the length times the mean of exp(-tau t).
        let dims = [10, 10, 10];
        let grid = GridGeometry::new(dims, DVec3::ZERO, DVec3::splat(10.0));
        for tau in [0.0, 0.7] {
            let t = Counters::new(&grid, 1, [1.0; 3], 1e12);
            let mut x0 = square(
                DVec3::new(3.1, 4.2, 2.9),
                DVec3::new(0.4, 0.3, 1.0).normalize(),
                1.3,
            );
            x0[2] += DVec3::new(0.1, -0.05, 0.02);
            let run = DVec3::new(1.7, 0.9, 4.6);
            let x1 = x0.map(|x| x + run);
            tube(&t, &x0, &x1, &[1.0; 3], DVec3::splat(tau), None);
            let want = run.length()
                * if tau > 0.0 {
                    (1.0 - (-tau).exp()) / tau
                } else {
                    1.0
                };
            let got = total(&t);
            assert!((got - want).abs() < 1e-9, "tau {tau}: {got} vs {want}");
        }
    }

    #[test]
    fn a_tilted_tubes_footprint_is_its_cross_section_in_the_layer() {
        // A square of side a perpendicular to a light tilted by theta from
        // the y axis within the x-y plane, crossing layers of y: its tube
        // cuts a layer's plane in an a / cos(theta) by a rectangle.
        let a = 0.5;
        for degrees in [0.0f64, 20.0, 40.0, 44.0] {
            let t = degrees.to_radians();
            let d = DVec3::new(t.sin(), -t.cos(), 0.0);
            let e1 = onto_layer(DVec3::new(t.cos(), t.sin(), 0.0) * a, d * 0.3, 1);
            let e2 = onto_layer(DVec3::Z * a, d * 0.3, 1);
            assert!(
                (e1 - DVec3::X * (a / t.cos())).length() < 1e-12,
                "{degrees}: {e1}"
            );
            assert!((e2 - DVec3::Z * a).length() < 1e-12, "{degrees}: {e2}");
        }
        // Moving nearly along the layer, the patch as it stands.
        let e = DVec3::new(0.3, 0.2, 0.1);
        assert_eq!(onto_layer(e, DVec3::new(1.0, 0.2, 0.0), 1), e);
    }

    #[test]
    fn a_beam_cut_in_two_along_its_line_deposits_as_one_tube() {
        // A run of steps through uniform space is deposited as one tube,
        // the same steps one by one as many: the two must agree. A tube's
        // box footprint is wrong over its last layers (the patch is tilted
        // to them: some of its rays have ended, others would run on), and
        // a tube that goes on along the same line makes the opposite error
        // over the same layers, wherever the joint falls within the cells
        // (where the path bends they do not cancel: docs/PERFORMANCE.md,
        // twenty-fourth session on issue 16).
        let dims = [16, 16, 4];
        let grid = GridGeometry::new(dims, DVec3::ZERO, DVec3::new(16.0, 16.0, 4.0));
        let flux = [1.0, 0.5, 0.25];
        for degrees in [20.0f64, 50.0, 70.0] {
            let t = degrees.to_radians();
            let d = DVec3::new(t.sin(), -t.cos(), 0.0);
            for phase in [0.0, 0.2, 0.37] {
                let (one, two) = (
                    Counters::new(&grid, 1, flux, 1e12),
                    Counters::new(&grid, 1, flux, 1e12),
                );
                // A plane wave's row of patches half a voxel across, each
                // meeting the joint at the same height.
                for k in 0..12 {
                    let x = 2.0 + k as f64 * 0.5 / t.cos();
                    let q1 = square(DVec3::new(x, 8.0 + phase, 2.0), d, 0.5);
                    let q0 = q1.map(|p| p - d * 3.0);
                    let q2 = q1.map(|p| p + d * 3.0);
                    assert_eq!(cut(&q0, &q1, 1.0), cut(&q0, &q2, 1.0));
                    tube(&one, &q0, &q2, &flux, DVec3::ZERO, None);
                    tube(&two, &q0, &q1, &flux, DVec3::ZERO, None);
                    tube(&two, &q1, &q2, &flux, DVec3::ZERO, None);
                }
                let (a, b) = (one.into_volume(), two.into_volume());
                let top = a.fluence.iter().cloned().fold(0.0f32, f32::max);
                // The joint's own cells are lit.
                let at_joint = (0..16).map(|i| a.fluence[[i, 8, 2, 0]]).fold(0.0, f32::max);
                assert!(
                    at_joint > 0.5 * top,
                    "{degrees} {phase}: {at_joint} of {top}"
                );
                for (x, y) in a.fluence.iter().zip(b.fluence.iter()) {
                    assert!((x - y).abs() <= 1e-6 * top, "{degrees} {phase}: {x} vs {y}");
                }
                for (x, y) in a.flux[0].iter().zip(b.flux[0].iter()) {
                    assert!((x - y).abs() <= 1e-6 * top, "{degrees} {phase}: {x} vs {y}");
                }
            }
        }
    }

    #[test]
    fn a_swept_footprint_holds_what_the_moving_box_covers() {
        // The time-integrated mass of a box moving uniformly, by brute
        // force: the box at many positions along its sweep, each cut at
        // the cell faces.
        for (centre, width, sweep) in [
            (3.37, 0.6, 0.0),
            (3.37, 0.0, 0.8),
            (2.02, 0.45, 0.9),
            (5.5, 1.3, 0.3),
            (4.99, 2.2, 1.0),
            (7.25, 0.8, 0.8),
        ] {
            let got = swept_parts(centre, width, sweep);
            let n = 20000;
            let mut want = std::collections::BTreeMap::<i64, f64>::new();
            for k in 0..n {
                let c = centre + sweep * ((k as f64 + 0.5) / n as f64 - 0.5);
                let (lo, hi) = (c - 0.5 * width, c + 0.5 * width);
                if width == 0.0 {
                    *want.entry(c.floor() as i64).or_default() += 1.0 / n as f64;
                    continue;
                }
                let mut x = lo;
                while x < hi {
                    let next = (x.floor() + 1.0).min(hi);
                    *want.entry(x.floor() as i64).or_default() += (next - x) / width / n as f64;
                    x = next;
                }
            }
            let sum: f64 = got.fraction[..got.count].iter().sum();
            assert!(
                (sum - 1.0).abs() < 1e-12,
                "{centre} {width} {sweep}: sum {sum}"
            );
            for (cell, w) in want {
                let k = cell - got.first;
                let g = if k >= 0 && (k as usize) < got.count {
                    got.fraction[k as usize]
                } else {
                    0.0
                };
                assert!(
                    (g - w).abs() < 2e-4,
                    "{centre} {width} {sweep}: cell {cell} {g} vs {w}"
                );
            }
        }
    }

    #[test]
    fn floor_is_the_libm_floor_on_cell_coordinates() {
        let mut rng = eikon_rng::SplitMix64::new(7);
        let mut xs = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            2.5,
            -2.5,
            1e15 + 0.5,
            -1e15 - 0.5,
        ];
        for k in -300i32..300 {
            let x = k as f64;
            xs.extend([x, x.next_up(), x.next_down(), x + 0.5, x - 0.5]);
        }
        for _ in 0..100_000 {
            xs.push((rng.unit() - 0.5) * 2f64.powi((rng.unit() * 50.0) as i32));
        }
        for x in xs {
            assert_eq!(floor(x), x.floor(), "{x}");
        }
        assert!(floor(f64::NAN).is_nan());
    }

    #[test]
    fn a_layer_tile_adds_each_cell_once_inside_and_outside_it() {
        // Cells within the tile and beyond it on every side, each met
        // several times: every cell's counters must hold its rounded sum,
        // as adding each amount straight to its own counters would.
        let grid = GridGeometry::new([1, 40, 40], DVec3::ZERO, DVec3::new(1.0, 40.0, 40.0));
        let t = Counters::new(&grid, 1, [1.0; 3], 1e6);
        let mut want = vec![[0.0f64; 6]; 40 * 40];
        let mut tile = Tile::new();
        let mut rng = eikon_rng::SplitMix64::new(3);
        for _ in 0..2 {
            for k in 0..400 {
                // The first cell places the tile around (20, 20).
                let at = if k == 0 {
                    [20, 20]
                } else {
                    [(rng.unit() * 40.0) as i64, (rng.unit() * 40.0) as i64]
                };
                let cell = (at[0] * 40 + at[1]) as usize;
                let amounts: [f64; 6] = std::array::from_fn(|c| {
                    let x = rng.unit() * 1000.0;
                    if c < 3 {
                        x
                    } else {
                        x - 500.0
                    }
                });
                tile.put(
                    at,
                    cell * 3,
                    [amounts[0], amounts[1], amounts[2]],
                    [amounts[3], amounts[4], amounts[5]],
                );
                for c in 0..6 {
                    want[cell][c] += amounts[c];
                }
            }
            // Two layers' worth into the same counters: the tile starts
            // empty again after a flush.
            tile.flush(&t, 0);
            assert_eq!((tile.len, tile.spill.len(), tile.origin), (0, 0, None));
        }
        let spilled = want.iter().enumerate().filter(|(i, w)| {
            let (b, c) = ((i / 40) as i64, (i % 40) as i64);
            w[0] > 0.0 && !((12..28).contains(&b) && (12..28).contains(&c))
        });
        assert!(spilled.count() > 100, "cells outside the tile were met");
        for (cell, w) in want.iter().enumerate() {
            for c in 0..3 {
                let got = t.fluence[cell * 3 + c].load(Ordering::Relaxed) as f64;
                let flux = t.flux[0][cell * 3 + c].load(Ordering::Relaxed) as f64;
                // Each layer's sum is rounded once: two roundings apart.
                assert!(
                    (got - w[c]).abs() <= 1.0,
                    "cell {cell} fluence {got} vs {}",
                    w[c]
                );
                assert!(
                    (flux - w[3 + c]).abs() <= 1.0,
                    "cell {cell} flux {flux} vs {}",
                    w[3 + c]
                );
            }
        }
    }
}
