//! Steps 1 and 2 of a simulation step: move every corner with the
//! equal-time ray equation [Ihrke07 eqs 14-15], deposit the tube the patch
//! sweeps (the track-length fluence, [`deposit::tube`]), attenuate the flux
//! along the way [Ihrke07 eq 18] and by Fresnel transmission at interfaces
//! ([`Interfaces::transmittance`], beyond the paper); with the paper's
//! deposit, recompute each patch's differential irradiance from its new
//! area [Ihrke07 eq 17]. Corners are kept on the eikonal shell `|v| = n`
//! (`ray::step_rk4_on_shell`), which makes equal time equal optical path.
//!
//! # The attenuation integral
//! [Ihrke07 eq 18]'s `int sigma_t / n dt` is taken along the patch's central
//! path, one step at a time, by the trapezoid rule: `sigma_t / n` is sampled at
//! the patch midpoint before and after the step (sigma_t trilinearly from
//! the extinction volume, n from the index field), averaged, and multiplied
//! by the step's `dt`. Since `dt = n ds` this is `int sigma_t ds`, the
//! optical depth. Outside the volume bounds sigma_t is zero, and a step
//! that crosses the bounds is charged for its part inside only
//! (`step_depth`).

use crate::deposit::{self, Counters};
use crate::patch::{area, span, Crossing, Patches, Split};
use crate::refine;
use eikon_grid::interface::Interfaces;
use eikon_grid::ray::{step_euler_on_shell, step_rk4_on_shell};
use eikon_grid::region::{refract, Region, Regions, SharpRay};
use eikon_grid::{
    EmptySpace, Form, GridGeometry, IndexField, Integrator, Medium, RayState, VoxelField,
};
use eikon_optics::fresnel;
use eikon_shader::{nothing, Module};
use glam::DVec3;
use rayon::prelude::*;

/// The WGSL of [`step_depth`] and [`straddle_weights`].
pub static WGSL: Module = Module {
    name: "propagate",
    requires: &[&eikon_grid::geometry::WGSL],
    declarations: nothing,
    text: include_str!("propagate.wgsl"),
};

/// The index field as light sees it: the voxel field inside the bounds,
/// and straight travel (no gradient) outside them.
#[derive(Clone, Copy)]
pub struct Bounded<'a> {
    field: VoxelField<'a>,
    grid: &'a GridGeometry,
}

impl<'a> Bounded<'a> {
    /// Index channel `channel` of `medium`.
    pub fn new(medium: &'a Medium, channel: usize) -> Self {
        Self {
            field: medium.field(channel),
            grid: &medium.geometry,
        }
    }
}

impl IndexField for Bounded<'_> {
    #[inline(always)]
    fn sample(&self, p: DVec3) -> (f64, DVec3) {
        let (n, g) = self.field.sample(p);
        if self.grid.contains(p) {
            (n, g)
        } else {
            (n, DVec3::ZERO)
        }
    }
}

/// `sigma_t / n` per channel at `p` (zero outside the bounds and in empty
/// space).
#[inline]
fn extinction_per_index(medium: &Medium, field: &Bounded, empty: &EmptySpace, p: DVec3) -> DVec3 {
    if !medium.geometry.contains(p) || empty.index_at(p).is_some() {
        return DVec3::ZERO;
    }
    medium.sample_rgb(&medium.extinction, p) / field.sample(p).0
}

/// `sigma_t / n` per channel of region `r` at `p` of `grid` with sharp interfaces:
/// its own extinction (its material's, exact up to its surface) over its
/// own index, in index channel `ch`; zero outside the bounds (the GPU's
/// `sharp_extinction_per_index`). The wavefront's and the photons' sharp
/// steps charge each piece of a step with it, in the region the piece
/// crosses (its end may lie on the surface).
pub(crate) fn region_extinction_per_index(
    grid: &GridGeometry,
    regions: &Regions,
    r: Region,
    p: DVec3,
    ch: usize,
) -> DVec3 {
    if !grid.contains(p) {
        return DVec3::ZERO;
    }
    regions.material(r).extinction_at(p) / regions.index(r, p, ch).0
}

/// [Ihrke07 eq 18]'s optical depth `int sigma_t / n dt` over one step of `dt`
/// from `x0` to `x1`, given `sigma_t / n` at both ends (zero outside the
/// bounds): the trapezoid rule, except that a step crossing the bounds is
/// charged only for its part inside, at the inside end's value. (The
/// trapezoid would charge half the step whatever its part inside: up to
/// `sigma_t h / 4` too much or too little for light entering obliquely.)
pub fn step_depth(
    grid: &GridGeometry,
    x0: DVec3,
    x1: DVec3,
    before: DVec3,
    after: DVec3,
    dt: f64,
) -> DVec3 {
    let (in0, in1) = (grid.contains(x0), grid.contains(x1));
    if in0 == in1 {
        return (before + after) * (0.5 * dt);
    }
    let inside = grid
        .clip_line(x0, x1 - x0)
        .map_or(0.0, |(t0, t1)| (t1.min(1.0) - t0.max(0.0)).max(0.0));
    (if in0 { before } else { after }) * (dt * inside)
}

/// What one step of a wavefront reads and where it deposits.
pub struct Step<'a> {
    /// The medium (extinction, boundary indicator).
    pub medium: &'a Medium,
    /// The index field of the wavefront's channel; `None` with sharp
    /// interfaces, which read each region's own index ([`Sharp`]).
    pub field: Option<&'a Bounded<'a>>,
    /// Its empty blocks.
    pub empty: &'a EmptySpace,
    /// Integrator.
    pub integrator: Integrator,
    /// Equal-time step, world units of optical path.
    pub dt: f64,
    /// Interface sides for Fresnel transmission; `None` leaves the flux
    /// to [Ihrke07 eq 18] alone (the paper).
    pub interfaces: Option<&'a Interfaces>,
    /// Index channel of the wavefront (its interface sides).
    pub channel: usize,
    /// Where the track-length fluence goes; `None` for the paper's
    /// deposit, which happens after the step.
    pub tally: Option<&'a Counters>,
    /// The wavefront's colour channel with dispersion.
    pub group: Option<usize>,
    /// Sharp interfaces ([`Sharp`]); `None`: the smoothed index.
    pub sharp: Option<&'a Sharp<'a>>,
    /// Straight runs of several steps through uniform space ([`Run`]).
    pub run: Run,
}

/// Straight runs through uniform space (beyond the paper): where a patch's
/// corners lie in blocks of one index and one extinction
/// ([`EmptySpace::uniform_at`], [`EmptySpace::reach`]; with sharp
/// interfaces, in one region whose index and extinction are constants, up
/// to its surface) it may take up to `max_steps` equal-time steps at once, straight, its tube deposited in one
/// pass ([`deposit::tube`]), without the index sampling, the
/// tessellation analysis and the list rebuilding in between. A run stops
/// short of any surface, and after any step at whose end the tessellation
/// analysis would do anything but keep the patch as it is (split it, end
/// it), so that the analysis after the run decides as it would have after
/// each of its steps. Patches ahead of the others in time meet nothing that
/// depends on the common time.
#[derive(Clone, Copy, Debug)]
pub struct Run {
    /// Most steps in one run; 1 runs none (the paper's deposit, which
    /// samples patches after every step).
    pub max_steps: usize,
    /// The tessellation analysis' rules.
    pub rules: Option<refine::Rules>,
    /// The simulation's step limit: no run takes a patch past it (its own
    /// clock, the optical path it has come over the step's), and a patch
    /// that ran ahead to it waits there while the others catch up, as if
    /// it had come step by step.
    pub until: usize,
}

impl Run {
    /// One step at a time.
    pub const NONE: Run = Run {
        max_steps: 1,
        rules: None,
        until: usize::MAX,
    };
}

/// Most steps one run through uniform space takes ([`Run`]).
pub const MAX_RUN: usize = 32;

/// What a run needs to know of a patch besides its corners and flux: its
/// flux when emitted and its tessellation depth (for the analysis).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Kin {
    pub flux0: [f64; 3],
    pub depth: u8,
}

/// How far a patch may go straight at once ([`uniform_run`]): the index
/// and extinction it sees all the way and the number of steps.
struct Reach {
    n: f64,
    sigma: DVec3,
    steps: usize,
}

/// [`Reach`] from the blocks of uniform space (smoothed interfaces): the
/// corners and the midpoint in uniform blocks of one index and extinction,
/// at most `most` steps, and the run within the cube of such blocks
/// ([`EmptySpace::reach`]). An absorbing patch whose first step would
/// leave that cube is left to the sampled step.
fn block_reach(step: &Step, x0: &[DVec3; 4], most: usize) -> Option<Reach> {
    let empty = step.empty;
    let m0 = (x0[0] + x0[1] + x0[2] + x0[3]) * 0.25;
    let (n, sigma) = empty.uniform_at(m0)?;
    if !x0.iter().all(|&x| empty.uniform_at(x) == Some((n, sigma))) {
        return None;
    }
    let unit = step.dt / n;
    let absorbs = sigma != DVec3::ZERO;
    let mut steps = 1;
    if most > 1 || absorbs {
        let reach = x0
            .iter()
            .map(|&x| empty.reach(x))
            .fold(f64::INFINITY, f64::min);
        if absorbs && reach < unit {
            return None;
        }
        steps = ((reach / unit).floor() as usize).clamp(1, most);
    }
    Some(Reach { n, sigma, steps })
}

/// [`Reach`] with sharp interfaces: the corners and the midpoint in one
/// region whose index and extinction are constants (its material's, exact
/// up to its surface), at most `most` steps, none of which takes a corner
/// to a surface (the exact crossing test along each corner's line) or, where the
/// region absorbs, out of the grid (nothing absorbs outside it,
/// [`step_depth`]). A patch whose first step would is left to the exact
/// step.
fn region_reach(
    step: &Step,
    sharp: &Sharp,
    x0: &[DVec3; 4],
    dirs: &[DVec3; 4],
    most: usize,
) -> Option<Reach> {
    let regions = sharp.regions;
    let m0 = (x0[0] + x0[1] + x0[2] + x0[3]) * 0.25;
    let r = regions.at(m0);
    let m = regions.material(r);
    if !regions.uniform(r) || m.extinction_grid.is_some() {
        return None;
    }
    if !x0.iter().all(|&x| regions.at(x) == r) {
        return None;
    }
    let n = regions.index(r, m0, step.channel).0;
    let unit = step.dt / n;
    let grid = &step.medium.geometry;
    let sigma = m.extinction;
    let mut steps = most;
    if sigma != DVec3::ZERO {
        for (&x, &d) in x0.iter().zip(dirs) {
            if !grid.contains(x) {
                return None;
            }
            let exit = grid.clip_line(x, d).map_or(0.0, |(_, t1)| t1);
            if exit < unit {
                return None;
            }
            steps = steps.min((exit / unit) as usize);
        }
    }
    // The crossing test skips a surface at its own start, so it starts a
    // little behind each corner: a corner on a surface (a step may end on
    // one) is then seen there, and left to the exact step, which knows
    // which way it crosses. A run ends short of a surface, never on it,
    // and never within `guard` of it: the next step's crossing test skips
    // what lies within `eps` of its start, so a run ending there (or a
    // surface just past the run's reach, rounded out of it) would let the
    // corner pass through the surface unseen, with no Snell and no Fresnel.
    let back = 1e-3 * unit;
    let guard = 4.0 * regions.eps();
    for (&x, &d) in x0.iter().zip(dirs) {
        let reach = back + steps as f64 * unit + guard;
        if let Some((_, hit)) = regions.next_surface(x - d * back, d, reach) {
            let fit = ((hit.t - back - guard) * (1.0 - 1e-9) / unit).floor();
            if fit < 1.0 {
                return None;
            }
            steps = steps.min(fit as usize);
        }
    }
    Some(Reach { n, sigma, steps })
}

/// Uniform space: with every corner and the midpoint of the patch in
/// uniform blocks of one index and one extinction ([`block_reach`]; with
/// sharp interfaces, in one region of a constant index and extinction,
/// [`region_reach`]) the step (or a [`Run`] of steps) is a straight line
/// through a constant index, losing `exp(-sigma l)` over a length `l`
/// [Ihrke07 eq 18], taken without sampling, and its tube deposited with
/// that loss spread along it. The flux is attenuated and the loss added to
/// `lost`. `false` (nothing changed) where the patch is not in uniform
/// space, or where a surface lies within the first step (the exact step
/// then crosses it).
fn uniform_run(
    step: &Step,
    sharp: Option<&Sharp>,
    corners: &mut [RayState; 4],
    flux: &mut [f64; 3],
    kin: Kin,
    lost: &mut Loss,
) -> bool {
    let Step {
        dt,
        tally,
        group,
        run,
        ..
    } = *step;
    let rules = run.rules.filter(|_| run.max_steps > 1);
    let mut most = if rules.is_some() { run.max_steps } else { 1 };
    if run.until != usize::MAX {
        let clock = (corners[0].opl / dt).round() as usize;
        let left = run.until.saturating_sub(clock);
        if left == 0 {
            // At the step limit ahead of the others: it waits.
            return true;
        }
        most = most.min(left);
    }
    let x0 = corners.map(|c| c.x);
    let dirs = corners.map(|c| c.v.normalize_or_zero());
    let found = match sharp {
        Some(sharp) => region_reach(step, sharp, &x0, &dirs, most),
        None => block_reach(step, &x0, most),
    };
    let Some(Reach { n, sigma, steps: k }) = found else {
        return false;
    };
    // Each step advances dt / n in space [Ihrke07 eqs 14-15] and loses
    // sigma dt / n of optical depth.
    let unit = dt / n;
    let per_step = sigma * unit;
    for (s, d) in corners.iter_mut().zip(dirs) {
        s.v = d * n;
    }
    // A run ends after the step at whose end the tessellation analysis
    // would split or end the patch (it then does so as if the patch had
    // come step by step), and where the patch has left the grid.
    let v = corners.map(|c| c.v * (dt / (n * n)));
    let grid = &step.medium.geometry;
    let mut from = x0;
    let mut taken = 0;
    let advance = |from: [DVec3; 4]| -> [DVec3; 4] { std::array::from_fn(|c| from[c] + v[c]) };
    let seen = |x: [DVec3; 4], steps: usize| {
        let depth = per_step * steps as f64;
        refine::Seen {
            x,
            v: corners.map(|c| c.v),
            flux: std::array::from_fn(|ch| flux[ch] * (-depth[ch]).exp()),
            flux0: kin.flux0,
            depth: kin.depth,
        }
    };
    // The analysis' verdict over the whole run from its two ends, where
    // that proves it ([`refine::retained_along`]): the corners end where
    // the steps one by one take them, without the analysis at each.
    if let Some(rules) = rules.filter(|_| k > 1) {
        let mut last = x0;
        for _ in 1..k {
            last = advance(last);
        }
        if refine::retained_along(grid, &rules, &x0, &seen(last, k - 1)) {
            from = advance(last);
            taken = k;
        }
    }
    while taken < k {
        from = advance(from);
        taken += 1;
        if taken == k {
            break;
        }
        let kept =
            rules.is_some_and(|rules| seen(from, taken).fate(grid, &rules) == refine::Fate::Retain);
        if !kept {
            break;
        }
    }
    let depth = per_step * taken as f64;
    // The run's tube in one pass.
    if let Some(t) = tally {
        deposit::tube(t, &x0, &from, flux, depth, group);
    }
    for ch in 0..3 {
        let kept = flux[ch] * (-depth[ch]).exp();
        lost.absorbed[ch] += flux[ch] - kept;
        flux[ch] = kept;
    }
    for (s, x) in corners.iter_mut().zip(from) {
        s.x = x;
        s.opl += taken as f64 * dt;
    }
    true
}

/// Sharp interfaces in the light simulation (`[grid] interfaces =
/// "sharp"`, [`eikon_grid::region`]): each corner crosses every surface on
/// its own, exactly, with Snell's law or total internal reflection there,
/// and the patch's flux takes each corner's Fresnel transmittance to the
/// power 1/4 (over a whole crossing the four make `1 - R`). A patch whose
/// corners disagree within a step (one refracts where another reflects
/// totally, or they cross different surfaces) is taken back to where the
/// step began and split in four, each traced again, until its corners agree;
/// a piece still torn at `min_span` goes on as a thin tube about its
/// centre ray, and a thin tube still torn is dropped and counted
/// ([`Loss::torn`]).
///
/// With [`Sharp::reflections`] the Fresnel-reflected part goes on as a
/// patch of its own ([`reflection`]) once all four corners have crossed a
/// surface, and is tallied as reflected only where it is not traced so.
pub struct Sharp<'a> {
    /// The scene's regions and surfaces.
    pub regions: &'a Regions<'a>,
    /// Patches no longer than this (world units) are not split further.
    pub min_span: f64,
    /// Fresnel transmission at the surfaces (else light passes unreflected).
    pub fresnel: bool,
    /// Trace the Fresnel-reflected light (else it leaves the beam and is
    /// counted as reflected).
    pub reflections: bool,
}

/// The index light sees with sharp interfaces: the region's own at each
/// point (for emission and the corners of new patches).
pub struct RegionIndex<'a> {
    /// The regions.
    pub regions: &'a Regions<'a>,
    /// The index channel.
    pub channel: usize,
}

impl IndexField for RegionIndex<'_> {
    #[inline]
    fn sample(&self, p: DVec3) -> (f64, DVec3) {
        self.regions.index(self.regions.at(p), p, self.channel)
    }
}

/// Flux that left the beams in one step, summed over a [`CHUNK`] of
/// patches.
#[derive(Clone, Copy, Debug, Default)]
pub struct Loss {
    /// RGB flux absorbed or scattered away [Ihrke07 eq 18].
    pub absorbed: [f64; 3],
    /// RGB flux reflected at an interface (Fresnel).
    pub reflected: [f64; 3],
    /// RGB flux of patches torn at a sharp interface and dropped
    /// ([`Sharp`]).
    pub torn: [f64; 3],
    /// How many pieces were dropped so.
    pub torn_pieces: usize,
    /// Reflected patches that carry on ([`reflection`]); their flux is
    /// taken off `reflected`.
    pub reflections: usize,
}

impl Loss {
    /// Add what `other` lost.
    #[inline]
    fn add(&mut self, other: &Loss) {
        for c in 0..3 {
            self.absorbed[c] += other.absorbed[c];
            self.reflected[c] += other.reflected[c];
            self.torn[c] += other.torn[c];
        }
        self.torn_pieces += other.torn_pieces;
        self.reflections += other.reflections;
    }
}

/// Patches per [`Loss`] of [`propagate`]: each chunk sums its patches'
/// losses in order, and the chunks fall at the same patches whatever the
/// thread count, so the sums are the same bits (a loss per patch took 88
/// bytes beside each patch's record, at the peak of the list). Small
/// enough that the threads share a short list evenly: a patch's step costs
/// from a few sums to a run's whole tube.
pub const CHUNK: usize = 64;

/// The four corner lists in [`CHUNK`]s, side by side.
fn corner_chunks(
    corner: &mut [Vec<RayState>; 4],
) -> impl IndexedParallelIterator<
    Item = (
        &mut [RayState],
        &mut [RayState],
        &mut [RayState],
        &mut [RayState],
    ),
> {
    let [c0, c1, c2, c3] = corner;
    (
        c0.par_chunks_mut(CHUNK),
        c1.par_chunks_mut(CHUNK),
        c2.par_chunks_mut(CHUNK),
        c3.par_chunks_mut(CHUNK),
    )
        .into_par_iter()
}

/// Advance every patch by one equal-time step `dt` (optical path, world
/// units), deposit the tube each patch sweeps into the tally, attenuate its
/// flux [Ihrke07 eq 18] and apply Fresnel transmission where it crosses an
/// interface. `losses` receives, per [`CHUNK`] of patches, the flux taken
/// out of the beam in this step.
pub fn propagate(patches: &mut Patches, step: &Step, losses: &mut Vec<Loss>) {
    losses.clear();
    losses.resize(patches.len().div_ceil(CHUNK), Loss::default());
    if let Some(sharp) = step.sharp {
        propagate_sharp(patches, step, sharp, losses);
        return;
    }
    let &Step {
        medium,
        field,
        empty,
        integrator,
        dt,
        interfaces,
        channel,
        tally,
        group,
        sharp: _,
        run: _,
    } = step;
    let field = field.expect("the smoothed index steps through its voxel field");
    let one = |a: &mut RayState,
               b: &mut RayState,
               c: &mut RayState,
               d: &mut RayState,
               flux: &mut [f64; 3],
               flux0: [f64; 3],
               depth: u8,
               lost: &mut Loss| {
        let mut corners = [*a, *b, *c, *d];
        if uniform_run(step, None, &mut corners, flux, Kin { flux0, depth }, lost) {
            [*a, *b, *c, *d] = corners;
            return;
        }
        let x0 = [a.x, b.x, c.x, d.x];
        let m0 = (x0[0] + x0[1] + x0[2] + x0[3]) * 0.25;
        let before = extinction_per_index(medium, field, empty, m0);
        for s in [&mut *a, &mut *b, &mut *c, &mut *d] {
            // On the shell |v| = n, so each corner advances exactly dt
            // of optical path and the four stay on one wavefront.
            match integrator {
                Integrator::Euler => step_euler_on_shell(field, Form::EqualTime, s, dt),
                _ => step_rk4_on_shell(field, Form::EqualTime, s, dt),
            }
        }
        let x1 = [a.x, b.x, c.x, d.x];
        let m1 = (x1[0] + x1[1] + x1[2] + x1[3]) * 0.25;
        let after = extinction_per_index(medium, field, empty, m1);
        let depth = step_depth(&medium.geometry, m0, m1, before, after, dt);
        if let Some(t) = tally {
            deposit::tube(t, &x0, &x1, flux, depth, group);
        }
        for ch in 0..3 {
            let kept = flux[ch] * (-depth[ch]).exp();
            lost.absorbed[ch] = flux[ch] - kept;
            flux[ch] = kept;
        }
        if let Some(faces) = interfaces {
            let v = (a.v + b.v + c.v + d.v) * 0.25;
            let t = faces.transmittance(medium, field, (m0 + m1) * 0.5, v, m1 - m0, channel);
            if t < 1.0 {
                for (f, r) in flux.iter_mut().zip(lost.reflected.iter_mut()) {
                    let kept = *f * t;
                    *r = *f - kept;
                    *f = kept;
                }
            }
        }
    };
    (
        corner_chunks(&mut patches.corner),
        patches.flux.par_chunks_mut(CHUNK),
        patches.flux0.par_chunks(CHUNK),
        patches.depth.par_chunks(CHUNK),
        losses.par_iter_mut(),
    )
        .into_par_iter()
        .for_each(|((a, b, c, d), flux, flux0, depth, sum)| {
            for k in 0..a.len() {
                let mut lost = Loss::default();
                one(
                    &mut a[k],
                    &mut b[k],
                    &mut c[k],
                    &mut d[k],
                    &mut flux[k],
                    flux0[k],
                    depth[k],
                    &mut lost,
                );
                sum.add(&lost);
            }
        });
}

/// A patch made by a split within a step ([`Sharp`]).
struct Piece {
    corners: [RayState; 4],
    flux: [f64; 3],
    flux0: [f64; 3],
    area0: f64,
    /// [`Patches::crossing`].
    crossing: Crossing,
}

/// [`propagate`] with sharp interfaces (see [`Sharp`]). A patch split
/// within the step keeps its slot for its first piece; the others, and a
/// patch's reflection, are appended after all patches, in patch order
/// (deterministic; the GPU's order too).
/// `losses` holds a zeroed [`Loss`] per [`CHUNK`] of patches.
fn propagate_sharp(patches: &mut Patches, step: &Step, sharp: &Sharp, losses: &mut [Loss]) {
    // One patch: `None` where it carries on alone in its slot, else its
    // pieces for after the list.
    #[allow(clippy::type_complexity)]
    let one = |(a, b, c, d, flux, flux0, area0, crossing, depth): (
        &mut RayState,
        &mut RayState,
        &mut RayState,
        &mut RayState,
        &mut [f64; 3],
        &mut [f64; 3],
        &mut f64,
        &mut Crossing,
        &mut u8,
    ),
               lost: &mut Loss|
     -> Option<Vec<Piece>> {
        let corners = [*a, *b, *c, *d];
        let kin = Kin {
            flux0: *flux0,
            depth: *depth,
        };
        let before = *crossing;
        if let Some(moved) = sharp_patch(step, sharp, &corners, flux, crossing, kin, lost) {
            [*a, *b, *c, *d] = moved;
            let start = corners.map(|c| c.x);
            let piece = crossing_done(
                step,
                sharp,
                &start,
                &moved,
                (flux, flux0),
                crossing,
                true,
                lost,
            )?;
            return Some(vec![Piece {
                flux0: *flux0,
                area0: *area0,
                ..piece
            }]);
        }
        // Torn: split where the step began and trace the pieces.
        let mut pieces = Vec::new();
        // The pieces' depth is the patch's after the split.
        split_and_trace(
            step,
            sharp,
            &corners,
            *flux,
            Kin {
                flux0: *flux0,
                depth: depth.saturating_add(1),
            },
            *area0,
            before,
            1,
            &mut pieces,
            lost,
        );
        *depth = depth.saturating_add(1);
        if pieces.is_empty() {
            // Every piece was dropped: the patch carries nothing on
            // and ends at the next refine.
            *flux = [0.0; 3];
            return None;
        }
        let p = pieces.remove(0);
        [*a, *b, *c, *d] = p.corners;
        *flux = p.flux;
        *flux0 = p.flux0;
        *area0 = p.area0;
        *crossing = p.crossing;
        Some(pieces)
    };
    let extra: Vec<Vec<(usize, Vec<Piece>)>> = (
        corner_chunks(&mut patches.corner),
        patches.flux.par_chunks_mut(CHUNK),
        patches.flux0.par_chunks_mut(CHUNK),
        patches.area0.par_chunks_mut(CHUNK),
        patches.crossing.par_chunks_mut(CHUNK),
        patches.depth.par_chunks_mut(CHUNK),
        losses.par_iter_mut(),
    )
        .into_par_iter()
        .enumerate()
        .map(
            |(chunk, ((a, b, c, d), flux, flux0, area0, crossing, depth, sum))| {
                let mut extra = Vec::new();
                for k in 0..a.len() {
                    let mut lost = Loss::default();
                    let patch = (
                        &mut a[k],
                        &mut b[k],
                        &mut c[k],
                        &mut d[k],
                        &mut flux[k],
                        &mut flux0[k],
                        &mut area0[k],
                        &mut crossing[k],
                        &mut depth[k],
                    );
                    if let Some(pieces) = one(patch, &mut lost) {
                        extra.push((chunk * CHUNK + k, pieces));
                    }
                    sum.add(&lost);
                }
                extra
            },
        )
        .collect();
    for (i, pieces) in extra.into_iter().flatten() {
        let depth = patches.depth[i];
        for p in pieces {
            for (list, c) in patches.corner.iter_mut().zip(p.corners) {
                list.push(c);
            }
            patches.flux.push(p.flux);
            patches.flux0.push(p.flux0);
            patches.area0.push(p.area0);
            patches.crossing.push(p.crossing);
            patches.depth.push(depth);
        }
    }
}

/// The Fresnel split of a patch whose corners have all crossed a surface
/// (`crossing.kept` below 1, the product of the factors `(1 - R)^(1/4)`
/// its corners took as they crossed, [`Crossing::kept`]; nothing else to do
/// while they have not; the crossing is over either way once they are in
/// one region). Until then the patch carries all its light on: its corners
/// cross at different steps, and the share the surface lets through is
/// Fresnel's transmittance over the whole patch from all four corners'
/// incidence, [`Reflection::transmitted`]. The factors, their geometric
/// mean, fall short of that where the transmittance is concave in the
/// incidence (towards grazing, at an object's outline: the shadow under a
/// glass sphere read low); they stand in where the surface is not found
/// ([`reflection`]: the corners met different surfaces, or it is out of
/// reach).
///
/// The reflected light, at the surface, is the patch's flux times `1 -
/// transmitted`, times `exp(restored)`: the patch was charged the
/// absorption of the region it entered since its corners crossed, which
/// the reflected part never entered ([`Reflection::restored`], given back
/// from the absorbed tally). If reflections are traced and it is not too
/// faint ([`REFLECT_MIN`]), it goes on as the reflected patch: its tube
/// from the surface deposited, and on its way back it loses
/// [`Reflection::depth`]. Else (and always for a piece of a torn patch,
/// `trace` false: the GPU has no slot for it) it is tallied as reflected.
#[allow(clippy::too_many_arguments)]
fn crossing_done(
    step: &Step,
    sharp: &Sharp,
    start: &[DVec3; 4],
    moved: &[RayState; 4],
    (flux, flux0): (&mut [f64; 3], &[f64; 3]),
    crossing: &mut Crossing,
    trace: bool,
    lost: &mut Loss,
) -> Option<Piece> {
    if *crossing == Crossing::NONE {
        return None;
    }
    let regions = sharp.regions;
    let to = regions.at(moved[0].x);
    if moved[1..].iter().any(|c| regions.at(c.x) != to) {
        return None;
    }
    let through = crossing.kept;
    *crossing = Crossing::NONE;
    if through == 1.0 {
        return None;
    }
    // (A patch that began the step in `to` crossed nothing in it.)
    let r = if start.iter().all(|&x| regions.at(x) == to) {
        None
    } else {
        reflection(
            regions,
            &step.medium.geometry,
            moved,
            to,
            step.dt,
            step.integrator,
            step.channel,
        )
    };
    let share = r.as_ref().map_or(through, |r| r.transmitted);
    let tallied = flux.map(|f| f * (1.0 - share));
    let f: [f64; 3] =
        std::array::from_fn(|c| tallied[c] * r.as_ref().map_or(1.0, |r| r.restored[c].exp()));
    for c in 0..3 {
        flux[c] *= share;
        lost.absorbed[c] -= f[c] - tallied[c];
    }
    let traced =
        r.filter(|_| trace && sharp.reflections && (0..3).any(|c| f[c] >= REFLECT_MIN * flux0[c]));
    let Some(r) = traced else {
        for (r, f) in lost.reflected.iter_mut().zip(f) {
            *r += f;
        }
        return None;
    };
    if let Some(t) = step.tally {
        deposit::tube(t, &r.hits, &r.corners.map(|c| c.x), &f, r.depth, step.group);
    }
    let out: [f64; 3] = std::array::from_fn(|c| f[c] * (-r.depth[c]).exp());
    for c in 0..3 {
        lost.absorbed[c] += f[c] - out[c];
    }
    lost.reflections += 1;
    Some(Piece {
        corners: r.corners,
        flux: out,
        flux0: [0.0; 3],
        area0: 0.0,
        crossing: Crossing::NONE,
    })
}

/// Reflections carrying less than this share of what their patch was
/// emitted with are not traced (they stay counted as reflected): a third
/// reflection at normal incidence on glass (`R^3`, 6.4e-5) adds less to
/// any cell than the deposit's own scatter, and each generation traced
/// adds a wavefront. (At 1e-2, which drops the second, the glass sphere
/// reads 1.0% low inside against independent photons instead of 0.8%.)
/// The GPU's too.
pub const REFLECT_MIN: f64 = 1e-3;

/// How far back, in patch spans, a reflection's corners look for the
/// surface they crossed ([`reflection`]): at incidence `theta` the corners
/// of a patch cross up to `tan theta` spans apart in time, so this covers
/// incidence up to about 83 degrees. The GPU's too.
pub const REACH_SPANS: f64 = 8.0;

/// Where a patch's Fresnel reflection is ([`reflection`]).
pub struct Reflection {
    /// The reflected corners, in an order that keeps the patch's
    /// orientation along its new direction of travel.
    pub corners: [RayState; 4],
    /// Where each (in that order) left the surface.
    pub hits: [DVec3; 4],
    /// The optical depth [Ihrke07 eq 18] the patch was charged in the
    /// region it entered since its corners crossed (their mean, as the
    /// patch is charged): the reflected part never entered it.
    pub restored: DVec3,
    /// The optical depth the reflected light loses from the surface to
    /// its corners (their mean), in the region it came from.
    pub depth: DVec3,
    /// The share of the patch's flux the surface let through: Fresnel's
    /// transmittance averaged over the patch from its corners' incidence
    /// ([`fresnel::patch_transmittance`]).
    pub transmitted: f64,
}

/// The Fresnel reflection of a patch whose corners `moved` have all
/// crossed one surface from one region into another, with the same time
/// on their clocks (`dt` apart from the step before): each corner is
/// followed back along its straight line to the surface (at most
/// [`REACH_SPANS`] spans of the patch and a step), its incident direction found from
/// Snell's law in reverse, and the reflected ray sent from there for the
/// optical path the corner has come since (in the region it came from,
/// [`Regions::step`]). A plane wave's reflection is thus exactly the mirror
/// image of the wavefront that went through. `None` unless every corner
/// finds the same surface with the same region behind it, a different one
/// from where it is. `to` is the region corner 0 is in. The back-trace
/// is straight: exact in a region of constant index, to the step's
/// curvature elsewhere. The optical depths (extinction in `grid`) are
/// charged as the steps charge them ([`step_depth`]).
pub fn reflection(
    regions: &Regions,
    grid: &GridGeometry,
    moved: &[RayState; 4],
    to: Region,
    dt: f64,
    integrator: Integrator,
    ch: usize,
) -> Option<Reflection> {
    // Every corner must have arrived: checked for all four before any is
    // followed back (the search for the surface is what costs).
    if moved[1..].iter().any(|s| regions.at(s.x) != to) {
        return None;
    }
    let reach = span(&moved.map(|c| c.x)) * REACH_SPANS + dt;
    let eps = regions.eps();
    let mut surface = None;
    let mut from = None;
    // Some corner meets the surface with R > 0 and none with R = 1: there
    // is a reflection (its flux is what the patch's own factors took,
    // `Crossing::kept`).
    let mut reflects = false;
    let mut corners = *moved;
    let mut hits = [DVec3::ZERO; 4];
    let mut incidence = [fresnel::Incidence {
        cos_i: 1.0,
        n1: 1.0,
        n2: 1.0,
    }; 4];
    let (mut restored, mut depth) = (DVec3::ZERO, DVec3::ZERO);
    let per_index = |r: Region, p: DVec3| region_extinction_per_index(grid, regions, r, p, ch);
    for k in 0..4 {
        let s = moved[k];
        let d = s.v.normalize_or_zero();
        // From just ahead, so that a corner that ended on the surface
        // finds it.
        let o = s.x + d * (2.0 * eps);
        let (obj, c) = regions.next_surface(o, -d, reach)?;
        if *surface.get_or_insert(obj) != obj {
            return None;
        }
        let p = o - d * c.t;
        let along = if c.normal.dot(d) >= 0.0 {
            c.normal
        } else {
            -c.normal
        };
        let behind = regions.at(p - along * eps);
        if behind == to || *from.get_or_insert(behind) != behind {
            return None;
        }
        let n1 = regions.index(behind, p, ch).0;
        let n2 = regions.index(to, p, ch).0;
        // Snell's law backwards: the incident gradient (|v| = n1).
        let vi = -refract(-d * n2, -along, n1)?;
        let cos_i = (vi / n1).dot(along);
        let r = fresnel::reflectance(cos_i, n1, n2);
        if r >= 1.0 || r.is_nan() {
            return None;
        }
        reflects |= r > 0.0;
        incidence[k] = fresnel::Incidence { cos_i, n1, n2 };
        // The optical path since the crossing (trapezoid in the index).
        let back = 0.5 * (n2 + regions.index(to, s.x, ch).0) * (c.t - 2.0 * eps).max(0.0);
        restored += step_depth(grid, p, s.x, per_index(to, p), per_index(to, s.x), back);
        let mut ray = SharpRay {
            s: RayState {
                x: p,
                v: vi - along * (2.0 * vi.dot(along)),
                opl: s.opl - back,
            },
            region: behind,
            ahead: None,
        };
        let mut left = back;
        for _ in 0..MAX_CROSSINGS {
            if left <= 0.0 {
                break;
            }
            let (xa, r) = (ray.s.x, ray.region);
            let st = regions.step(&mut ray, Form::EqualTime, integrator, left, ch);
            left -= st.used;
            let xb = ray.s.x;
            depth += step_depth(grid, xa, xb, per_index(r, xa), per_index(r, xb), st.used);
            if !st.at_surface {
                break;
            }
        }
        // A corner that crossed at the end of its step is sent back from
        // the surface itself.
        regions.settle(&mut ray);
        corners[k] = ray.s;
        hits[k] = p;
    }
    if !reflects {
        return None;
    }
    // A mirror image reverses the corners' winding: 0 3 2 1 restores it.
    Some(Reflection {
        corners: [corners[0], corners[3], corners[2], corners[1]],
        hits: [hits[0], hits[3], hits[2], hits[1]],
        restored: restored * 0.25,
        depth: depth * 0.25,
        transmitted: fresnel::patch_transmittance(&incidence),
    })
}

/// Split the patch `corners` (where the step began) in four and trace each
/// piece ([`sharp_patch`]), splitting again while torn, down to
/// [`MAX_SPLIT_LEVEL`] levels (`level` is the quarters'); pieces go to
/// `out`. A torn piece no longer than [`Sharp::min_span`] goes on instead
/// as a thin tube about its centre ray ([`THIN_SPAN`]), at the next
/// level: a ray, as a photon is, so that the light on both sides of a
/// silhouette carries on. A thin tube still torn is dropped, its flux to
/// `lost.torn`.
#[allow(clippy::too_many_arguments)]
fn split_and_trace(
    step: &Step,
    sharp: &Sharp,
    corners: &[RayState; 4],
    flux: [f64; 3],
    kin: Kin,
    area0: f64,
    crossing: Crossing,
    level: u32,
    out: &mut Vec<Piece>,
    lost: &mut Loss,
) {
    let drop = |lost: &mut Loss| {
        for (t, f) in lost.torn.iter_mut().zip(flux) {
            *t += f;
        }
        lost.torn_pieces += 1;
    };
    if level > MAX_SPLIT_LEVEL {
        drop(lost);
        return;
    }
    // A piece that has just finished crossing a surface is split by
    // Fresnel as a patch is; its reflection is not traced.
    let settle = |start: &[RayState; 4],
                  moved: &[RayState; 4],
                  f: &mut [f64; 3],
                  flux0: &[f64; 3],
                  through: &mut Crossing,
                  lost: &mut Loss| {
        let start = start.map(|c| c.x);
        crossing_done(step, sharp, &start, moved, (f, flux0), through, false, lost);
    };
    let field = RegionIndex {
        regions: sharp.regions,
        channel: step.channel,
    };
    if span(&corners.map(|c| c.x)) <= sharp.min_span {
        let thin = thin_about_centre(corners, sharp.min_span * THIN_SPAN, &field);
        let (mut f, mut through) = (flux, crossing);
        match sharp_patch(step, sharp, &thin, &mut f, &mut through, kin, lost) {
            Some(moved) => {
                settle(&thin, &moved, &mut f, &kin.flux0, &mut through, lost);
                out.push(Piece {
                    corners: moved,
                    flux: f,
                    flux0: kin.flux0,
                    area0,
                    crossing: through,
                })
            }
            None => drop(lost),
        }
        return;
    }
    let flux0 = kin.flux0;
    let split = Split::Quarters;
    let areas = [0, 1, 2, 3].map(|q| area(&split.child(corners, q).map(|r| r.x)));
    let total: f64 = areas.iter().sum();
    for (q, ar) in areas.iter().enumerate() {
        let share = if total > 0.0 { ar / total } else { 0.25 };
        let mut child = split.child(corners, q);
        for r in child.iter_mut() {
            // Bilinear v has the right direction but not |v| = n.
            r.v = r.v.normalize_or_zero() * field.sample(r.x).0;
        }
        let mut f = flux.map(|v| v * share);
        let part = Kin {
            flux0: flux0.map(|v| v * share),
            depth: kin.depth,
        };
        // A piece carries its parent's share of the flux through the
        // surface it straddles (its own corners take this step's factors).
        let mut through = crossing;
        match sharp_patch(step, sharp, &child, &mut f, &mut through, part, lost) {
            Some(moved) => {
                settle(&child, &moved, &mut f, &part.flux0, &mut through, lost);
                out.push(Piece {
                    corners: moved,
                    flux: f,
                    flux0: part.flux0,
                    area0: area0 * share,
                    crossing: through,
                })
            }
            None => split_and_trace(
                step,
                sharp,
                &child,
                f,
                part,
                area0 * share,
                crossing,
                level + 1,
                out,
                lost,
            ),
        }
    }
}

/// A patch `thin` across about the centre ray of `c`: its corners drawn
/// in towards the centre, every one moving as the centre ray does.
fn thin_about_centre(c: &[RayState; 4], thin: f64, field: &RegionIndex) -> [RayState; 4] {
    let x = (c[0].x + c[1].x + c[2].x + c[3].x) * 0.25;
    let v = (c[0].v + c[1].v + c[2].v + c[3].v).normalize_or_zero() * field.sample(x).0;
    let shrink = thin / span(&c.map(|r| r.x)).max(thin);
    c.map(|r| RayState {
        x: x + (r.x - x) * shrink,
        v,
        ..r
    })
}

/// One step of one patch with sharp interfaces: the corners moved, its flux
/// attenuated [Ihrke07 eq 18], its tube deposited, and the Fresnel factors
/// of the corners that crossed a surface taken into `crossing` (the patch
/// is split when all have crossed, [`crossing_done`]); `None` (nothing
/// changed) when its corners disagree.
fn sharp_patch(
    step: &Step,
    sharp: &Sharp,
    corners: &[RayState; 4],
    flux: &mut [f64; 3],
    crossing: &mut Crossing,
    kin: Kin,
    lost: &mut Loss,
) -> Option<[RayState; 4]> {
    let Step {
        medium,
        integrator,
        dt,
        channel,
        tally,
        group,
        ..
    } = *step;
    let regions = sharp.regions;
    let x0 = corners.map(|c| c.x);
    let mut moved = *corners;
    if uniform_run(step, Some(sharp), &mut moved, flux, kin, lost) {
        return Some(moved);
    }
    let per_index =
        |r: Region, p: DVec3| region_extinction_per_index(&medium.geometry, regions, r, p, channel);
    // Each corner: the step's whole optical path, surface by surface, and
    // the optical depth [Ihrke07 eq 18] of each piece in the region it
    // crosses (so a step through a surface is charged for the part on each
    // side, not half and half); the patch loses the corners' mean.
    let mut first: [Option<Crossed>; 4] = [None; 4];
    let mut factor = 1.0;
    // Each corner's Fresnel transmittance over the step's crossings, and
    // its region as the step began.
    let mut passed = [1.0; 4];
    let mut owner: [Region; 4] = [None; 4];
    // Each corner's optical depth over the step, and where its path first
    // bent (refracted or reflected at a surface).
    let mut depths = [DVec3::ZERO; 4];
    let mut bends: [Option<Bend>; 4] = [None; 4];
    for (k, s) in moved.iter_mut().enumerate() {
        let mut ray = SharpRay {
            s: *s,
            region: regions.at(s.x),
            ahead: None,
        };
        owner[k] = ray.region;
        let mut left = dt;
        let mut on_surface = false;
        for _ in 0..MAX_CROSSINGS {
            let (xa, r) = (ray.s.x, ray.region);
            let st = regions.step(&mut ray, Form::EqualTime, integrator, left, channel);
            on_surface = st.at_surface;
            left -= st.used;
            // A crossing leaves the ray on the surface: the piece ends there.
            let xb = ray.s.x;
            depths[k] += step_depth(
                &medium.geometry,
                xa,
                xb,
                per_index(r, xa),
                per_index(r, xb),
                st.used,
            );
            if let Some(ev) = st.event {
                if first[k].is_none() {
                    bends[k] = Some(Bend {
                        at: xb,
                        depth: depths[k],
                        time: (dt - left) / dt,
                    });
                }
                first[k].get_or_insert(Crossed {
                    surface: ev.surface,
                    total: ev.total,
                    from: ev.from,
                    to: ev.to,
                });
                if !ev.total {
                    factor *= (1.0 - ev.reflectance).powf(0.25);
                    passed[k] *= 1.0 - ev.reflectance;
                }
            }
            if !st.at_surface || left <= 0.0 {
                break;
            }
        }
        if on_surface {
            regions.settle(&mut ray);
        }
        *s = ray.s;
    }
    // A patch is torn when its corners part ways for good: two corners
    // meet the same surface and one refracts where the other reflects
    // totally; two meet different surfaces that are not layers of one path
    // (the region one enters is not the one the other leaves); or a corner
    // that crossed nothing is still where the others came from and, straight
    // ahead within the patch's reach, meets none of their surfaces (it passes
    // beside the object: a silhouette). Corners one layer apart (an oblique
    // wavefront through a thin wall) and corners already beyond are not torn.
    // The four corners' first crossings, without allocating (this runs for
    // every patch at every step).
    let events = || first.iter().flatten();
    for (i, a) in first.iter().enumerate() {
        let Some(a) = a else { continue };
        for b in first[i + 1..].iter().flatten() {
            let together = if a.surface == b.surface {
                a.total == b.total
            } else {
                a.to == b.from || b.to == a.from || (a.from == b.from && a.to == b.to)
            };
            if !together {
                return None;
            }
        }
    }
    if events().any(|e| !e.total) {
        let reach = span(&moved.map(|c| c.x)).max(span(&x0)) * 2.0 + dt;
        for (k, s) in moved.iter().enumerate() {
            if first[k].is_some() {
                continue;
            }
            let at = regions.at(s.x);
            if !events().any(|e| e.from == at) || events().any(|e| e.to == at) {
                continue;
            }
            let d = s.v.normalize_or_zero();
            let ahead = regions.next_surface(s.x, d, reach).map(|(obj, _)| obj);
            if !ahead.is_some_and(|o| events().any(|e| e.surface == o)) {
                return None;
            }
        }
    }
    let x1 = moved.map(|c| c.x);
    // (Until its corners have all crossed, the patch's reflected share is
    // charged the absorption beyond the surface with the rest; it is given
    // back when the crossing is done, `crossing_done`.)
    let depth = (depths[0] + depths[1] + depths[2] + depths[3]) * 0.25;
    if let Some(t) = tally {
        let passed = if sharp.fresnel { passed } else { [1.0; 4] };
        let weights = straddle_weights(&owner, *crossing, &passed);
        bent_tube(
            t,
            (&x0, &x1),
            &bends,
            (&depths, depth),
            flux,
            &weights,
            group,
        );
    }
    for ch in 0..3 {
        let k = flux[ch] * (-depth[ch]).exp();
        lost.absorbed[ch] += flux[ch] - k;
        flux[ch] = k;
    }
    if crossing.into == 0 {
        if let Some(c) = first.iter().flatten().find(|c| !c.total) {
            crossing.into = region_code(c.to);
        }
    }
    if sharp.fresnel {
        crossing.kept *= factor;
    }
    Some(moved)
}

/// A region as [`Crossing::into`] names it (0 names none).
pub fn region_code(r: Region) -> u32 {
    match r {
        None => 1,
        Some(i) => i as u32 + 2,
    }
}

/// Per corner, the share of a patch's light about it, before and after
/// its path bends in a step, while the patch straddles a surface
/// (`crossing` as the step began, [`Crossing`]; `owner`, each corner's
/// region then): 1 where the corner has not
/// crossed, and beyond the surface what it let through, `1 - R`. The
/// patch carries all its light on until its corners have all crossed
/// ([`crossing_done`]), so without these its tube would put the reflected
/// share beyond the surface too, in the cells the surface cuts. A corner
/// that crossed before the step is one in the region the crossing goes
/// into; its `1 - R` is found from the factors `(1 - R)^(1/4)` the corners
/// there took, `crossing.kept`, as their geometric mean (exact for a whole
/// patch; a piece of a torn patch or a child of a split holds its
/// ancestor's factors). A corner that crosses in the step takes its own
/// transmittance over it, `passed`, after its bend. The GPU's
/// `straddle_weights` (`propagate.wgsl`).
pub fn straddle_weights(
    owner: &[Region; 4],
    crossing: Crossing,
    passed: &[f64; 4],
) -> ([f64; 4], [f64; 4]) {
    let mut before = [1.0; 4];
    if crossing.into != 0 && crossing.kept < 1.0 {
        let beyond = owner.map(|r| region_code(r) == crossing.into);
        let m = beyond.iter().filter(|&&b| b).count();
        if m > 0 {
            let w = crossing.kept.powf(4.0 / m as f64);
            for (b, &is) in before.iter_mut().zip(&beyond) {
                if is {
                    *b = w;
                }
            }
        }
    }
    let after = std::array::from_fn(|k| before[k] * passed[k]);
    (before, after)
}

/// Where a corner's path first bent in a step, at a surface it crossed
/// or reflected from totally.
#[derive(Clone, Copy)]
struct Bend {
    /// The point on the surface.
    at: DVec3,
    /// The optical depth [Ihrke07 eq 18] the corner lost before it.
    depth: DVec3,
    /// The share of the step's time it took to get there.
    time: f64,
}

/// Deposit the tube of a sharp step whose corners went from `x0` to `x1`,
/// carrying `flux`, where a corner's path may have bent at a surface
/// (`bends`, its first bend; `depths`, each corner's optical depth over
/// the step, and `depth`, their mean, what the patch loses). A bent path is longer than the chord from its start to its
/// end, and lies off it: a straight tube would deposit too little light
/// beside the surface, on both sides (about `L delta^2 / 12` of a step `L`
/// turned by `delta`, averaged over where the bend falls), and put some in
/// the wrong cells. So the tube goes in two pieces, through each corner's
/// bend; a corner that did not bend goes straight, its midpoint where the
/// bent corners' mean share of the step's time puts it. The two pieces are
/// cut into the same sub-patches (the more of the two each would take), so
/// that each sub-patch's path runs on through the bend: cut apart, a
/// sub-patch of the first piece would end between two of the second's, and
/// where the corners move apart (some refracted, some not) the paths of
/// one and of two sub-patches lie differently across the layers: the cell
/// a surface cuts and the one above it traded light. Each piece loses
/// the corners' mean optical depth over it, as the whole step loses their
/// mean. Later bends within the step (a second surface within a step) are
/// cut straight. The light over the patch is weighted per corner by
/// `weights` before and after the bends ([`straddle_weights`]).
fn bent_tube(
    t: &Counters,
    (x0, x1): (&[DVec3; 4], &[DVec3; 4]),
    bends: &[Option<Bend>; 4],
    (depths, depth): (&[DVec3; 4], DVec3),
    flux: &[f64; 3],
    (before_w, after_w): &([f64; 4], [f64; 4]),
    group: Option<usize>,
) {
    let bent = bends.iter().flatten().count();
    if bent == 0 {
        let n = deposit::cut(x0, x1, t.voxel());
        deposit::tube_cut(t, (x0, x1), flux, before_w, depth, group, n);
        return;
    }
    let time = bends.iter().flatten().map(|b| b.time).sum::<f64>() / bent as f64;
    let mut mid = [DVec3::ZERO; 4];
    let mut before = DVec3::ZERO;
    for k in 0..4 {
        let (at, d) = match bends[k] {
            Some(b) => (b.at, b.depth),
            None => (x0[k] + (x1[k] - x0[k]) * time, depths[k] * time),
        };
        mid[k] = at;
        before += d * 0.25;
    }
    let after = (depth - before).max(DVec3::ZERO);
    // Both pieces in the same sub-patches, so that each runs on through
    // the bend (see above).
    let v = t.voxel();
    let (a, b) = match (deposit::cut(x0, &mid, v), deposit::cut(&mid, x1, v)) {
        (Some(a), Some(b)) => {
            let n = Some((a.0.max(b.0), a.1.max(b.1)));
            (n, n)
        }
        other => other,
    };
    deposit::tube_cut(t, (x0, &mid), flux, before_w, before, group, a);
    let through: [f64; 3] = std::array::from_fn(|c| flux[c] * (-before[c]).exp());
    deposit::tube_cut(t, (&mid, x1), &through, after_w, after, group, b);
}

/// The first surface a corner crossed in a step.
#[derive(Clone, Copy, PartialEq)]
struct Crossed {
    surface: usize,
    total: bool,
    from: Region,
    to: Region,
}

/// Most surfaces one corner crosses in one step (a guard: a step is half
/// a voxel, and surfaces closer than that are rare). The GPU's too.
pub(crate) const MAX_CROSSINGS: usize = 16;

/// Span of the thin tube a torn piece goes on as at the smallest split
/// ([`Sharp::min_span`]), as a fraction of it: thin enough that the tube
/// deposits its centre ray's chord.
pub(crate) const THIN_SPAN: f64 = 1.0 / 64.0;

/// Most levels of a torn patch's tree within one step ([`Sharp`]): a piece
/// split this often, or a thin tube, still torn is dropped. The GPU's too
/// (the depth of its walk).
pub(crate) const MAX_SPLIT_LEVEL: u32 = 8;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bent_tube_deposits_the_bent_paths_length() {
        // A thin patch whose corners all bend at one point: its fluence
        // (times the cell volume) adds up to the two legs' length, not the
        // chord's, and each leg loses its own optical depth.
        let g = GridGeometry::new([8, 8, 8], DVec3::splat(-1.0), DVec3::splat(1.0));
        let tally = Counters::new(&g, 1, [1.0; 3], 1e9);
        let thin = |p: DVec3| {
            let e = 1e-5;
            [
                p,
                p + DVec3::X * e,
                p + DVec3::new(e, 0.0, e),
                p + DVec3::Z * e,
            ]
        };
        let (a, b, c) = (
            DVec3::new(-0.6, 0.5, 0.1),
            DVec3::new(0.05, 0.02, 0.13),
            DVec3::new(0.7, 0.1, -0.4),
        );
        let bend = Bend {
            at: b,
            depth: DVec3::new(0.3, 0.0, 0.0),
            time: 0.4,
        };
        let bends = thin(b).map(|at| Some(Bend { at, ..bend }));
        let depths = [DVec3::new(0.5, 0.0, 0.0); 4];
        bent_tube(
            &tally,
            (&thin(a), &thin(c)),
            &bends,
            (&depths, depths[0]),
            &[1.0; 3],
            &([1.0; 4], [1.0; 4]),
            None,
        );
        let v = tally.into_volume();
        let cell = (2.0f64 / 8.0).powi(3);
        let sum = |ch: usize| v.fluence.slice(ndarray::s![.., .., .., ch]).sum() as f64 * cell;
        let (l1, l2) = ((b - a).length(), (c - b).length());
        // Channel 1 loses nothing: the legs' length.
        assert!(
            (sum(1) / (l1 + l2) - 1.0).abs() < 1e-5,
            "{} vs {}",
            sum(1),
            l1 + l2
        );
        assert!((l1 + l2) / (c - a).length() > 1.1, "the path bends");
        // Channel 0: the first leg loses 0.3, the second 0.2 after it.
        let leg = |l: f64, tau: f64| l * (1.0 - (-tau).exp()) / tau;
        let want = leg(l1, 0.3) + (-0.3f64).exp() * leg(l2, 0.2);
        assert!((sum(0) / want - 1.0).abs() < 1e-5, "{} vs {want}", sum(0));
    }

    #[test]
    fn a_step_into_the_volume_is_charged_for_its_part_inside() {
        let g = GridGeometry::new([4, 4, 4], DVec3::ZERO, DVec3::ONE);
        let sigma = DVec3::new(2.0, 4.0, 0.0);
        // From x = -0.1 (outside) to x = 0.3: three quarters inside.
        let (a, b) = (DVec3::new(-0.1, 0.5, 0.5), DVec3::new(0.3, 0.5, 0.5));
        let d = step_depth(&g, a, b, DVec3::ZERO, sigma, 0.4);
        assert!((d - sigma * 0.3).length() < 1e-12, "{d}");
        // And out of it, from the inside end.
        let d = step_depth(
            &g,
            b + DVec3::X * 0.6,
            b + DVec3::X * 0.8,
            sigma,
            DVec3::ZERO,
            0.2,
        );
        assert!((d - sigma * 0.1).length() < 1e-12, "{d}");
        // Inside: the trapezoid.
        let d = step_depth(&g, a + DVec3::X * 0.2, b, sigma, sigma * 3.0, 0.2);
        assert!((d - sigma * 0.4).length() < 1e-12, "{d}");
    }
}
