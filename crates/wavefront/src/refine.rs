//! Step 3: tessellation analysis and the rebuilt patch list
//! [Ihrke07 sec 5.2.3].
//!
//! Each patch becomes Eliminate (0), Retain (1) or Tessellate (4):
//! * eliminated when its transmittance `flux / flux0` has fallen below the
//!   threshold in every channel (absorbed), when it has left the volume
//!   (its midpoint is outside and its direction never brings it back), or
//!   when its orientation has flipped against its direction of travel (it
//!   passed through a caustic, where the intensity law breaks down);
//! * tessellated when its longest edge exceeds `split` voxels;
//! * retained otherwise.
//!
//! The counts feed a [`HistoPyramid`]; every output slot then finds its
//! source patch and, for a tessellated one, which of its four children it
//! becomes: quarters, or four strips across the long side of a sliver
//! ([`Split`]). A child's corners are bilinear in the parent's (positions,
//! `v` and optical path), with `v` rescaled to `|v| = n` at its new
//! position; the flux is shared in proportion to the children's areas, so
//! splitting conserves it exactly.

use crate::histopyramid::HistoPyramid;
use crate::patch::{area, normal, span, Crossing, Patches, Split};
use eikon_grid::{GridGeometry, IndexField, RayState};
use eikon_shader::{Consts, Module};
use rayon::prelude::*;

/// The WGSL of [`below`], of [`Incident::at`] (`refine_incident_at`, and
/// `point_irradiance` for a point or spot light), of [`faint`]
/// (`refine_faint`) and of `gone` (`refine_gone`), which the GPU's
/// tessellation analysis calls.
pub static WGSL: Module = Module {
    name: "refine",
    requires: &[
        &eikon_shader::VECTOR,
        &eikon_optics::spot::WGSL,
        &eikon_grid::geometry::WGSL,
    ],
    declarations: refine_declarations,
    text: include_str!("refine.wgsl"),
};

/// What an [`Incident`] is, in WGSL's `Incident.kind`: a plane wave.
pub const INCIDENT_UNIFORM: u32 = 0;
/// A point light.
pub const INCIDENT_POINT: u32 = 1;
/// A spot light.
pub const INCIDENT_SPOT: u32 = 2;

fn refine_declarations() -> String {
    Consts::new()
        .u32("INCIDENT_UNIFORM", INCIDENT_UNIFORM)
        .u32("INCIDENT_POINT", INCIDENT_POINT)
        .u32("INCIDENT_SPOT", INCIDENT_SPOT)
        .wgsl()
        .to_owned()
}

/// Why patches left the list, and how much flux they took with them.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Ended {
    /// Patches that left the volume.
    pub exited: usize,
    /// Patches whose transmittance fell below the threshold.
    pub absorbed: usize,
    /// Patches split and dimmed until too faint to follow
    /// ([`Rules::faint`]).
    pub faint: usize,
    /// Patches that flipped at a caustic.
    pub caustic: usize,
    /// RGB flux carried out of the volume.
    pub exited_flux: [f64; 3],
    /// RGB flux of patches dropped by the threshold or at a caustic.
    pub culled_flux: [f64; 3],
    /// RGB flux of patches too faint to follow, still travelling (light
    /// held by total internal reflection ends this way, split ever finer).
    pub faint_flux: [f64; 3],
}

/// Fate of one patch (the GPU's `FATE_*` are these values).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u32)]
pub(crate) enum Fate {
    Exit,
    Absorbed,
    Faint,
    Caustic,
    Retain,
    Split,
}

/// Settings of the analysis.
/// Relative slack of the split span: a patch emitted exactly at the split
/// size is not split for the rounding of its corners.
pub(crate) const SPLIT_SLACK: f64 = 1e-9;

#[derive(Clone, Copy, Debug)]
pub struct Rules {
    /// Tessellate above this span, world units.
    pub split_span: f64,
    /// Eliminate below this transmittance.
    pub threshold: f64,
    /// Never grow the list beyond this many patches: would-be splits are
    /// retained instead (and counted).
    pub max_patches: usize,
    /// Never tessellate a patch more often than this since emission: a
    /// patch straddling a discontinuity of the ray map (the silhouette of
    /// an object) stretches without bound, and so would its descendants.
    pub max_depth: u8,
    /// Eliminate patches whose orientation has flipped (the paper's rule,
    /// `--deposit paper`): the intensity law breaks down at a caustic. The
    /// track-length deposit needs no area, so by default light carries on
    /// through the focus and is split when it grows again.
    pub cull_caustics: bool,
    /// Do not split a patch whose irradiance has fallen below this fraction
    /// of [`Rules::incident`] in every channel ([`below`]; 0: split
    /// whatever it carries).
    pub dim: f64,
    /// The light's unobstructed irradiance per channel, for [`Rules::dim`]
    /// and [`Rules::faint`].
    pub incident: Incident,
    /// Eliminate a patch whose flux is below this many times the
    /// unobstructed irradiance at its midpoint in every channel ([`below`];
    /// an area, world units^2; 0: never); for a patch over
    /// [`Rules::corner_rays`] across, a quarter of its flux at each corner
    /// ([`faint`]).
    pub faint: f64,
    /// The span (world units) over which a patch's tube goes along its
    /// four corner rays ([`crate::deposit::corner_ray_span`]; infinite:
    /// never).
    pub corner_rays: f64,
}

/// The irradiance per colour channel (of those a wavefront carries) a
/// light would give at a point with nothing in the way: across the beam of
/// a directional light, `P w / (4 pi r^2)` from a point or spot light (`w`
/// the cone weight).
#[derive(Clone, Copy, Debug)]
pub enum Incident {
    /// A plane wave of this irradiance per channel.
    Uniform([f64; 3]),
    /// A point or spot light.
    Point {
        /// Where it is.
        position: glam::DVec3,
        /// Its power per channel.
        power: [f64; 3],
        /// Its cone (axis, half-angle and falloff in degrees).
        cone: Option<(glam::DVec3, f64, f64)>,
    },
}

impl Incident {
    /// For `light`, with its channels weighted by `mask`.
    pub fn new(light: &eikon_grid::Light, mask: [f64; 3]) -> Self {
        use eikon_grid::Light;
        let carried = |p: glam::DVec3| [p.x * mask[0], p.y * mask[1], p.z * mask[2]];
        match light {
            Light::Directional { power, .. } => Incident::Uniform(carried(*power)),
            Light::Point { position, power } => Incident::Point {
                position: *position,
                power: carried(*power),
                cone: None,
            },
            Light::Spot {
                position,
                direction,
                angle,
                falloff,
                power,
            } => Incident::Point {
                position: *position,
                power: carried(*power),
                cone: Some((*direction, *angle, *falloff)),
            },
        }
    }

    /// The irradiance per channel at `x`.
    #[inline]
    pub fn at(&self, x: glam::DVec3) -> [f64; 3] {
        match *self {
            Incident::Uniform(e) => e,
            Incident::Point {
                position,
                power,
                cone,
            } => {
                let d = x - position;
                let r2 = d.length_squared();
                let g = eikon_optics::spot::cone_weight(d / r2.sqrt(), cone)
                    / (4.0 * std::f64::consts::PI * r2);
                power.map(|p| p * g)
            }
        }
    }
}

/// Whether `flux` is below `k` times the irradiance `incident` in every
/// channel the light carries (`incident` above 0): the tests of
/// [`Rules::faint`] (`k` an area) and [`Rules::dim`] (`k` times the
/// patch's area), channel by channel, so that how a patch is followed in
/// one channel never depends on how another is absorbed (a glass opaque to
/// red passes green and blue as a clear one does).
#[inline]
pub fn below(flux: &[f64; 3], k: f64, incident: &[f64; 3]) -> bool {
    (0..3).all(|c| incident[c] <= 0.0 || flux[c] < k * incident[c])
}

/// Patches [`refine`] must not split now, whatever their size, by their
/// corner positions: with sharp interfaces, a patch whose corners lie in
/// different regions (part of it through a surface, part not yet), whose
/// new corners would mix a refracted direction with an unrefracted one.
pub type Hold<'a> = &'a (dyn Fn(&[glam::DVec3; 4]) -> bool + Sync);

/// Reusable buffers of [`refine`].
#[derive(Default)]
pub struct Scratch {
    fate: Vec<Fate>,
    counts: Vec<u8>,
    source: Vec<u32>,
    part: Vec<u8>,
    pyramid: HistoPyramid,
}

/// Whether a particle at `x` moving along `d` has left `grid` for good
/// (outside, and heading away from it).
#[inline]
pub(crate) fn gone(grid: &GridGeometry, x: glam::DVec3, d: glam::DVec3) -> bool {
    !grid.contains(x) && grid.clip_line(x, d).is_none_or(|(_, t1)| t1 <= 0.0)
}

fn fate(p: &Patches, i: usize, grid: &GridGeometry, rules: &Rules) -> Fate {
    let seen = Seen {
        x: p.positions(i),
        v: [0, 1, 2, 3].map(|c| p.corner[c][i].v),
        flux: p.flux[i],
        flux0: p.flux0[i],
        depth: p.depth[i],
    };
    seen.fate(grid, rules)
}

/// What the tessellation analysis reads of one patch.
pub(crate) struct Seen {
    /// Its corners.
    pub x: [glam::DVec3; 4],
    /// Their ray velocities.
    pub v: [glam::DVec3; 4],
    /// Its flux.
    pub flux: [f64; 3],
    /// Its flux when emitted.
    pub flux0: [f64; 3],
    /// How often it has been tessellated since emission.
    pub depth: u8,
}

impl Seen {
    /// The patch's fate under `rules` (before any [`Hold`]).
    pub(crate) fn fate(&self, grid: &GridGeometry, rules: &Rules) -> Fate {
        let x = self.x;
        let mid = (x[0] + x[1] + x[2] + x[3]) * 0.25;
        let dir = || {
            self.v
                .iter()
                .map(|v| v.normalize_or_zero())
                .sum::<glam::DVec3>()
                .normalize_or_zero()
        };
        let gone = |x: glam::DVec3, d: glam::DVec3| gone(grid, x, d);
        if rules.cull_caustics {
            // The paper's deposit reads the midpoint only.
            if gone(mid, dir()) {
                return Fate::Exit;
            }
        } else if (0..4).all(|c| gone(x[c], self.v[c])) {
            // The track-length deposit lights every cell a patch covers, so a
            // patch across the bounds stays until each corner has left (and a
            // patch torn apart, its midpoint inside long after its corners
            // parted ways across a silhouette, goes then too).
            return Fate::Exit;
        }
        let (f, f0) = (self.flux, self.flux0);
        if (0..3).all(|c| f[c] <= rules.threshold * f0[c]) {
            return Fate::Absorbed;
        }
        // A patch that has been split and dimmed until it carries less than
        // `faint` of what a voxel of the unobstructed light carries cannot
        // change any cell by more than that fraction: light trapped and
        // bouncing in absorbing glass would otherwise keep splitting for
        // thousands of steps. It ends still travelling, its flux counted as
        // trapped: in clear glass that is most of what total internal
        // reflection holds (it splits without dimming until it is faint).
        // The light's own irradiance at the midpoint, once for both tests
        // (a point light's costs a square root and its cone).
        let incident = rules.incident.at(mid);
        let wide = span(&x);
        if rules.faint > 0.0 && faint(grid, rules, &self.flux, &x, &self.v, wide, &incident) {
            return Fate::Faint;
        }
        if rules.cull_caustics && normal(&x).dot(dir()) <= 0.0 {
            return Fate::Caustic;
        }
        if wide > rules.split_span * (1.0 + SPLIT_SLACK) && self.depth < rules.max_depth {
            if rules.dim > 0.0 {
                // A patch spread so thin that its irradiance is a small part
                // of what the light would give there unobstructed adds little
                // to any cell: it is not worth more patches (it deposits along
                // its corner rays once it is over two voxels across,
                // `deposit::tube`).
                if below(&f, rules.dim * area(&x), &incident) {
                    return Fate::Retain;
                }
            }
            Fate::Split
        } else {
            Fate::Retain
        }
    }
}

/// Whether a patch with corners `x` moving along `v`, carrying `flux` and
/// `span` across, is too faint to follow ([`Rules::faint`]): its flux
/// below `faint` times the light's irradiance at its midpoint, `incident`
/// ([`below`]). A patch over [`Rules::corner_rays`] across deposits a
/// quarter of its flux along each of its corner rays and nothing between
/// them (`deposit::tube`), so it is too faint where each corner inside the
/// grid carries its quarter below that limit of the irradiance there, and
/// each corner outside has left for good: its midpoint may lie far from
/// all of them (a patch torn across an object's silhouette, one corner
/// held inside the object by total internal reflection while the others
/// went on past it). The GPU's `refine_faint` (`refine.wgsl`) is the same
/// rule.
pub fn faint(
    grid: &GridGeometry,
    rules: &Rules,
    flux: &[f64; 3],
    x: &[glam::DVec3; 4],
    v: &[glam::DVec3; 4],
    span: f64,
    incident: &[f64; 3],
) -> bool {
    if span <= rules.corner_rays {
        return below(flux, rules.faint, incident);
    }
    let quarter = flux.map(|f| 0.25 * f);
    (0..4).all(|c| {
        if grid.contains(x[c]) {
            below(&quarter, rules.faint, &rules.incident.at(x[c]))
        } else {
            gone(grid, x[c], v[c])
        }
    })
}

/// Relative margin of [`retained_along`]'s bounds: far above the rounding
/// of corners moved by repeated steps and of the attenuated flux, so that
/// a bound that holds does so for the values [`Seen::fate`] computes.
const ALONG_MARGIN: f64 = 1e-9;

/// Whether [`Seen::fate`] retains a patch at every step of a straight run
/// from corners `first` to the state `last` (corners moving along
/// straight lines at constant speed, flux falling, the tessellation depth
/// the same), proved from the two ends alone; `false` where
/// that cannot be shown (the caller then asks at each step). Each test of
/// the analysis is bounded over the run:
/// - a corner inside the grid at both ends (with a margin) is inside
///   all along (the box is convex), so the patch has not left;
/// - the flux only falls, so a channel above the absorbed and faint
///   limits at the end was above them before; a point light's
///   irradiance is bounded by its value at the nearest approach of the
///   midpoint's path (a spot's cone is not bounded: `false`);
/// - an edge's squared length is a convex quadratic of the time, so the
///   span over the run is at most the larger of its ends'.
pub(crate) fn retained_along(
    grid: &GridGeometry,
    rules: &Rules,
    first: &[glam::DVec3; 4],
    last: &Seen,
) -> bool {
    if rules.cull_caustics {
        return false;
    }
    // (A patch over the corner rays' span is faint by its corners; the
    // span along a straight run is largest at an end.)
    let wide = rules.corner_rays * (1.0 - ALONG_MARGIN);
    if rules.faint > 0.0 && (span(first) > wide || span(&last.x) > wide) {
        return false;
    }
    let up = 1.0 + ALONG_MARGIN;
    let pad = (grid.max - grid.min) * ALONG_MARGIN;
    let inner = |x: glam::DVec3| x.cmpge(grid.min + pad).all() && x.cmple(grid.max - pad).all();
    if !(0..4).any(|c| inner(first[c]) && inner(last.x[c])) {
        return false;
    }
    let (f, f0) = (last.flux, last.flux0);
    if !(0..3).any(|c| f[c] > rules.threshold * f0[c] * up) {
        return false;
    }
    if rules.faint > 0.0 {
        let most = match rules.incident {
            Incident::Uniform(e) => e,
            Incident::Point {
                position,
                power,
                cone: None,
            } => {
                let mid = |x: &[glam::DVec3; 4]| (x[0] + x[1] + x[2] + x[3]) * 0.25;
                let (a, b) = (mid(first), mid(&last.x));
                let d = b - a;
                let t = if d.length_squared() > 0.0 {
                    ((position - a).dot(d) / d.length_squared()).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                let r = (a + d * t - position).length() * (1.0 - ALONG_MARGIN);
                if r.is_nan() || r <= 0.0 {
                    return false;
                }
                power.map(|p| p / (4.0 * std::f64::consts::PI * r * r))
            }
            Incident::Point { cone: Some(_), .. } => return false,
        };
        if !(0..3).any(|c| most[c] > 0.0 && f[c] >= rules.faint * most[c] * up) {
            return false;
        }
    }
    let limit = rules.split_span * (1.0 + SPLIT_SLACK) * (1.0 - ALONG_MARGIN);
    last.depth >= rules.max_depth || (span(first) <= limit && span(&last.x) <= limit)
}

/// Analyse every patch of `p`, rebuild the list into `next` through the
/// HistoPyramid and swap it into `p`. Returns what left the list; `held`
/// counts splits refused by `max_patches`. Three steps, as the GPU's
/// kernels: [`tally`] (the fates and what left), [`grant`] (the split
/// grants: each patch's count of 0, 1 or 4) and [`rebuild`] (the walk).
#[allow(clippy::too_many_arguments)]
pub fn refine<F: IndexField + ?Sized>(
    p: &mut Patches,
    next: &mut Patches,
    scratch: &mut Scratch,
    field: &F,
    grid: &GridGeometry,
    rules: &Rules,
    held: &mut usize,
    hold: Option<Hold>,
) -> Ended {
    let (ended, kept, splits) = tally(p, scratch, grid, rules, hold);
    grant(scratch, rules.max_patches, kept, splits, held);
    if kept == p.len() {
        // Every patch retained: the list stands as it is.
        return ended;
    }
    rebuild(p, next, scratch, field);
    ended
}

/// Each patch's fate (in parallel), and in patch order (deterministic
/// sums) what left the list, the patches kept and the splits asked for.
fn tally(
    p: &Patches,
    scratch: &mut Scratch,
    grid: &GridGeometry,
    rules: &Rules,
    hold: Option<Hold>,
) -> (Ended, usize, usize) {
    let n = p.len();
    scratch.fate.clear();
    scratch.fate.resize(n, Fate::Retain);
    scratch.fate.par_iter_mut().enumerate().for_each(|(i, f)| {
        *f = fate(p, i, grid, rules);
        if matches!(f, Fate::Split) && hold.is_some_and(|h| h(&p.positions(i))) {
            *f = Fate::Retain;
        }
    });
    let mut ended = Ended::default();
    let mut splits = 0usize;
    let mut kept = 0usize;
    for (i, f) in scratch.fate.iter().enumerate() {
        let add = |acc: &mut [f64; 3]| (0..3).for_each(|c| acc[c] += p.flux[i][c]);
        match f {
            Fate::Exit => {
                ended.exited += 1;
                add(&mut ended.exited_flux);
            }
            Fate::Absorbed => {
                ended.absorbed += 1;
                add(&mut ended.culled_flux);
            }
            Fate::Faint => {
                ended.faint += 1;
                add(&mut ended.faint_flux);
            }
            Fate::Caustic => {
                ended.caustic += 1;
                add(&mut ended.culled_flux);
            }
            Fate::Retain => kept += 1,
            Fate::Split => splits += 1,
        }
    }
    (ended, kept, splits)
}

/// The patches' counts in the next list: 0 for those that left, 1 for
/// those retained, 4 for a split granted. Splits that would overflow the
/// list are refused (counted in `held`); patches earlier in the list get
/// the room first.
fn grant(scratch: &mut Scratch, max_patches: usize, kept: usize, splits: usize, held: &mut usize) {
    let mut room = max_patches.saturating_sub(kept + splits) / 3;
    scratch.counts.clear();
    scratch.counts.extend(scratch.fate.iter().map(|f| match f {
        Fate::Retain => 1,
        Fate::Split => {
            if room > 0 {
                room -= 1;
                4
            } else {
                *held += 1;
                1
            }
        }
        _ => 0,
    }));
}

/// The next list from the counts: the HistoPyramid's walk finds each
/// slot's source patch and part, and a slot copies its patch or becomes
/// one of its children; then `next` is swapped into `p`.
fn rebuild<F: IndexField + ?Sized>(
    p: &mut Patches,
    next: &mut Patches,
    scratch: &mut Scratch,
    field: &F,
) {
    scratch.pyramid.build(&scratch.counts);
    scratch
        .pyramid
        .expand_into(&mut scratch.source, &mut scratch.part);
    let total = scratch.source.len();
    let blank = RayState {
        x: glam::DVec3::ZERO,
        v: glam::DVec3::ZERO,
        opl: 0.0,
    };
    for c in next.corner.iter_mut() {
        c.clear();
        c.resize(total, blank);
    }
    next.flux.clear();
    next.flux.resize(total, [0.0; 3]);
    next.flux0.clear();
    next.flux0.resize(total, [0.0; 3]);
    next.area0.clear();
    next.area0.resize(total, 0.0);
    next.crossing.clear();
    next.crossing.resize(total, Crossing::NONE);
    next.depth.clear();
    next.depth.resize(total, 0);

    let counts = &scratch.counts;
    let [n0, n1, n2, n3] = &mut next.corner;
    (
        n0.par_iter_mut(),
        n1.par_iter_mut(),
        n2.par_iter_mut(),
        n3.par_iter_mut(),
        next.flux.par_iter_mut(),
        next.flux0.par_iter_mut(),
        next.area0.par_iter_mut(),
        next.crossing.par_iter_mut(),
        next.depth.par_iter_mut(),
        scratch.source.par_iter(),
        scratch.part.par_iter(),
    )
        .into_par_iter()
        .for_each(
            |(a, b, c, d, flux, flux0, area0, crossing, depth, &src, &part)| {
                let i = src as usize;
                // A child keeps its parent's share of the flux through a
                // surface it straddles.
                *crossing = p.crossing[i];
                let parent = [0, 1, 2, 3].map(|k| p.corner[k][i]);
                if counts[i] == 1 {
                    [*a, *b, *c, *d] = parent;
                    *flux = p.flux[i];
                    *flux0 = p.flux0[i];
                    *area0 = p.area0[i];
                    *depth = p.depth[i];
                    return;
                }
                let split = Split::of(&parent.map(|r| r.x));
                let areas = [0, 1, 2, 3].map(|q| area(&split.child(&parent, q).map(|r| r.x)));
                let total: f64 = areas.iter().sum();
                let share = if total > 0.0 {
                    areas[part as usize] / total
                } else {
                    0.25
                };
                let mut child = split.child(&parent, part as usize);
                for r in child.iter_mut() {
                    // Bilinear v has the right direction but not |v| = n.
                    r.v = r.v.normalize_or_zero() * field.sample(r.x).0;
                }
                [*a, *b, *c, *d] = child;
                *flux = p.flux[i].map(|f| f * share);
                *flux0 = p.flux0[i].map(|f| f * share);
                *area0 = p.area0[i] * share;
                *depth = p.depth[i] + 1;
            },
        );
    std::mem::swap(p, next);
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    /// The tessellation's tests go channel by channel: a patch is below a
    /// share only when every channel the light carries is, so one channel
    /// still bright keeps it whatever the others (summed, red's absorption
    /// ended green sooner), and a channel the light does not carry never
    /// holds it.
    #[test]
    fn below_is_every_carried_channel_below_its_own_share() {
        let incident = [2.0, 1.0, 0.5];
        // Each channel under 0.1 of its own irradiance.
        assert!(below(&[0.19, 0.09, 0.04], 0.1, &incident));
        // Green at its share: not below, though the sum (0.33) is under
        // 0.1 of the summed irradiance (0.35).
        assert!(!below(&[0.19, 0.1, 0.04], 0.1, &incident));
        // Red gone (absorbed): green and blue decide alone, as they would
        // with red still there.
        assert!(below(&[0.0, 0.09, 0.04], 0.1, &incident));
        assert!(!below(&[0.0, 0.11, 0.04], 0.1, &incident));
        // A channel the light does not carry is ignored.
        assert!(below(&[5.0, 0.09, 0.04], 0.1, &[0.0, 1.0, 0.5]));
        // No light in any channel: nothing to follow.
        assert!(below(&[0.0; 3], 0.1, &[0.0; 3]));
    }

    /// A patch over the corner rays' span is faint by its corners: one
    /// corner held near a point light inside the grid while the other three
    /// have gone on far beyond it (a patch torn across a silhouette) ends
    /// once the quarter that corner carries is below the faint limit there,
    /// however dim the light at its far-off midpoint; it stays while that
    /// quarter is above it, or while a corner outside the grid is still
    /// heading back in. A patch within the span keeps the midpoint's test.
    #[test]
    fn a_patch_wider_than_the_corner_rays_is_faint_by_its_corners() {
        let grid = GridGeometry::new([10, 10, 10], DVec3::ZERO, DVec3::ONE);
        let h = grid.voxel_size();
        let light = DVec3::new(0.5, 0.5, -0.5);
        let rules = Rules {
            split_span: h,
            threshold: 1e-9,
            max_patches: usize::MAX,
            max_depth: 0,
            cull_caustics: false,
            dim: 0.0,
            incident: Incident::Point {
                position: light,
                power: [1.0; 3],
                cone: None,
            },
            faint: 1e-4 * h * h,
            corner_rays: crate::deposit::corner_ray_span(h),
        };
        let limit = |x: DVec3| rules.faint * rules.incident.at(x)[0];
        // Corner 0 inside the grid; the others far out and heading away.
        let held = DVec3::new(0.5, 0.5, 0.3);
        let x = [
            held,
            DVec3::new(6.0, 0.5, 0.3),
            DVec3::new(6.0, 6.0, 0.3),
            DVec3::new(0.5, 6.0, 0.3),
        ];
        let away = [DVec3::Z, DVec3::X, DVec3::new(1.0, 1.0, 0.0), DVec3::Y];
        let mid = (x[0] + x[1] + x[2] + x[3]) * 0.25;
        assert!(span(&x) > rules.corner_rays);
        // Twice the midpoint's limit; its quarter below the held corner's.
        let flux = 2.0 * limit(mid);
        assert!(flux * 0.25 < limit(held) && flux > limit(mid));
        let seen = |x: [DVec3; 4], v: [DVec3; 4], f: f64| Seen {
            x,
            v,
            flux: [f; 3],
            flux0: [1.0; 3],
            depth: 0,
        };
        assert_eq!(seen(x, away, flux).fate(&grid, &rules), Fate::Faint);
        // Its quarter above the limit at the held corner: followed.
        let bright = 4.0 * limit(held) * 1.01;
        assert_eq!(seen(x, away, bright).fate(&grid, &rules), Fate::Retain);
        // A corner outside coming back in may yet light the grid.
        let back = [DVec3::Z, -DVec3::X, DVec3::new(1.0, 1.0, 0.0), DVec3::Y];
        assert_eq!(seen(x, back, flux).fate(&grid, &rules), Fate::Retain);
        // Faint at the held corner, but not at a second corner inside the
        // grid farther from the light: followed.
        let quarter = 0.99 * limit(held);
        let two = [x[0], DVec3::new(0.5, 0.5, 0.95), x[2], x[3]];
        assert!(quarter > limit(two[1]));
        assert_eq!(
            seen(two, away, 4.0 * quarter).fate(&grid, &rules),
            Fate::Retain
        );
        assert_eq!(
            seen(x, away, 4.0 * quarter).fate(&grid, &rules),
            Fate::Faint
        );
        // Within the span, the midpoint's test as before.
        let small = x.map(|c| held + (c - held) * (0.9 * rules.corner_rays / span(&x)));
        let m = (small[0] + small[1] + small[2] + small[3]) * 0.25;
        for (f, fate) in [(0.99, Fate::Faint), (1.01, Fate::Retain)] {
            let s = seen(small, away, f * limit(m));
            assert_eq!(s.fate(&grid, &rules), fate, "{f} of the midpoint's limit");
        }
    }

    /// Where [`retained_along`] proves a straight run retained from its
    /// ends, the analysis asked at every step of it retains the patch: runs
    /// of patches that grow, shrink, fold, leave the grid, fade and pass a
    /// point light, each followed step by step as `propagate`'s runs are.
    /// The proof must also hold for most runs that stay quiet, and fail
    /// for those that do not.
    #[test]
    fn a_run_proved_retained_from_its_ends_is_retained_at_every_step() {
        let grid = GridGeometry::new([32, 32, 32], DVec3::ZERO, DVec3::ONE);
        let h = grid.voxel_size();
        let mut rng = eikon_rng::SplitMix64::new(17);
        let mut u = || rng.unit();
        let (mut proved, mut quiet, mut wrong) = (0, 0, 0);
        for case in 0..20_000 {
            let incident = match case % 3 {
                0 => Incident::Uniform([1.0, 0.5, 0.0]),
                _ => Incident::Point {
                    position: DVec3::new(u(), u(), u()) * 1.2 - 0.1,
                    power: [3.0, 2.0, 1.0],
                    cone: None,
                },
            };
            let rules = Rules {
                split_span: h,
                threshold: 1e-2,
                max_patches: usize::MAX,
                max_depth: if case % 7 == 0 { 0 } else { 8 },
                cull_caustics: false,
                dim: 0.05,
                incident,
                faint: 1e-3 * h * h,
                // Some patches grow past the corner rays' span within
                // the run (their faint test then reads the corners).
                corner_rays: if case % 4 == 0 {
                    h * (0.5 + u())
                } else {
                    4.0 * h
                },
            };
            // A patch about a split span across, anywhere in or near the
            // grid, its corners on their own straight lines.
            let centre = DVec3::new(u(), u(), u()) * 1.1 - 0.05;
            let size = h * (0.2 + 1.0 * u());
            let x0: [DVec3; 4] = std::array::from_fn(|c| {
                let corner =
                    DVec3::new((c == 1 || c == 2) as u8 as f64, (c >= 2) as u8 as f64, 0.0);
                centre + (corner - 0.5) * size + (DVec3::new(u(), u(), u()) - 0.5) * 0.1 * size
            });
            let dir = (DVec3::new(u(), u(), u()) - 0.5).normalize();
            let spread = h * 0.02 * (u() - 0.3);
            let v: [DVec3; 4] =
                std::array::from_fn(|c| dir * (0.5 * h) + (x0[c] - centre) * spread / size);
            // Flux over three decades, some of it fading below the
            // absorbed (1e-5) and faint (about 1e-6) limits within the run.
            let flux = [u(), u(), u()].map(|f| 1e-3 * 10f64.powf(-3.0 * f));
            let flux0 = [1e-3; 3];
            let per_step = DVec3::new(u(), u(), u()) * 0.1 * (case % 2) as f64;
            let k = 2 + (u() * 40.0) as usize;
            let seen = |x: [DVec3; 4], j: usize| {
                let depth = per_step * j as f64;
                Seen {
                    x,
                    v,
                    flux: std::array::from_fn(|c| flux[c] * (-depth[c]).exp()),
                    flux0,
                    depth: 1,
                }
            };
            let mut at = vec![x0];
            for j in 1..k {
                at.push(std::array::from_fn(|c| at[j - 1][c] + v[c]));
            }
            let every = (1..k).all(|j| seen(at[j], j).fate(&grid, &rules) == Fate::Retain);
            let bound = retained_along(&grid, &rules, &x0, &seen(at[k - 1], k - 1));
            wrong += (bound && !every) as usize;
            proved += bound as usize;
            quiet += every as usize;
        }
        assert_eq!(wrong, 0);
        assert!(
            proved > quiet * 3 / 5,
            "proved {proved} of {quiet} quiet runs"
        );
        assert!(quiet < 15_000, "only {quiet} of 20000 runs stay quiet");
    }
}
