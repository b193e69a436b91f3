//! The wavefront patch list, structure-of-arrays.
//!
//! A patch is a quadrilateral of four light particles `c0, c1, c2, c3`
//! (in order around it) that share one wavefront: all four were launched
//! together and move with the equal-time ray equation [Ihrke07 eqs 14-15], so
//! they stay on a surface of constant optical path. Its flux is RGB power in
//! watts; its differential irradiance is that flux over its current area
//! (the intensity law, [Ihrke07 eqs 16-17]).

use eikon_grid::RayState;
use eikon_shader::{Consts, Module};
use glam::DVec3;

fn patch_declarations() -> String {
    Consts::new()
        .u32("SPLIT_QUARTERS", Split::Quarters as u32)
        .u32("SPLIT_STRIPS_S", Split::StripsS as u32)
        .u32("SPLIT_STRIPS_T", Split::StripsT as u32)
        .wgsl()
        .to_string()
}

/// The WGSL of the patch geometry: [`normal`], [`area`], [`span`], the
/// bilinear map and [`Split`].
pub static WGSL: Module = Module {
    name: "patch",
    requires: &[],
    declarations: patch_declarations,
    text: include_str!("patch.wgsl"),
};

/// All live patches of one wavefront, one array per attribute.
#[derive(Clone, Debug, Default)]
pub struct Patches {
    /// Corner particles: position, eikonal gradient `v` (|v| = n) and the
    /// optical path travelled, for corners 0..4.
    pub corner: [Vec<RayState>; 4],
    /// RGB flux carried, W, after attenuation along the path [Ihrke07 eq 18].
    pub flux: Vec<[f64; 3]>,
    /// RGB flux the patch would carry without attenuation: its share of
    /// the light's emitted power. `flux / flux0` is its transmittance.
    pub flux0: Vec<[f64; 3]>,
    /// Area when emitted (the patch's share of it after tessellation).
    pub area0: Vec<f64>,
    /// The crossing of a sharp interface the patch is in, if any.
    pub crossing: Vec<Crossing>,
    /// Times the patch's ancestors were tessellated (0 when emitted).
    pub depth: Vec<u8>,
}

/// A patch's crossing of a sharp interface, while its corners straddle
/// it: the patch carries all its light on until every corner has crossed,
/// when it is split into what the surface lets through and its reflection
/// (`propagate::crossing_done`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Crossing {
    /// The product of the Fresnel factors `(1 - R)^(1/4)` its corners (or,
    /// for a piece of a torn patch, its ancestor's) took as they crossed,
    /// not yet applied. 1 between crossings.
    pub kept: f64,
    /// The region its corners cross into (`propagate::region_code`; 0
    /// between crossings): a corner there has crossed, and the light about
    /// it is what the surface let through (`propagate::straddle_weights`).
    pub into: u32,
}

impl Crossing {
    /// Between crossings.
    pub const NONE: Crossing = Crossing { kept: 1.0, into: 0 };
}

impl Patches {
    /// Bytes one patch takes at most: in the list, and again in the list
    /// the tessellation rebuilds it into, each of which `Vec`'s amortized
    /// growth may leave with capacity for up to twice the patches it
    /// holds. What a wavefront of `n` patches holds at most is
    /// `n * BYTES_PER_PATCH`.
    pub const BYTES_PER_PATCH: usize = 2
        * 2
        * (4 * std::mem::size_of::<RayState>()
            + 2 * std::mem::size_of::<[f64; 3]>()
            + std::mem::size_of::<f64>()
            + std::mem::size_of::<Crossing>()
            + std::mem::size_of::<u8>());

    /// Number of patches.
    pub fn len(&self) -> usize {
        self.flux.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.flux.is_empty()
    }

    /// Remove every patch, keeping the memory.
    pub fn clear(&mut self) {
        self.corner.iter_mut().for_each(Vec::clear);
        self.flux.clear();
        self.flux0.clear();
        self.area0.clear();
        self.crossing.clear();
        self.depth.clear();
    }

    /// Append a patch.
    pub fn push(&mut self, corners: [RayState; 4], flux: [f64; 3]) {
        let area = area(&corners.map(|c| c.x));
        for (list, c) in self.corner.iter_mut().zip(corners) {
            list.push(c);
        }
        self.flux.push(flux);
        self.flux0.push(flux);
        self.area0.push(area);
        self.crossing.push(Crossing::NONE);
        self.depth.push(0);
    }

    /// Corner positions of patch `i`.
    #[inline]
    pub fn positions(&self, i: usize) -> [DVec3; 4] {
        [0, 1, 2, 3].map(|c| self.corner[c][i].x)
    }

    /// RGB differential irradiance of patch `i`, W/m^2: its flux over its
    /// area [Ihrke07 eq 17] (the attenuation of [Ihrke07 eq 18] is in the
    /// flux); 0 for a patch of no area.
    #[inline]
    pub fn irradiance(&self, i: usize) -> [f64; 3] {
        let ar = area(&self.positions(i));
        self.flux[i].map(|f| if ar > 0.0 { f / ar } else { 0.0 })
    }

    /// Midpoint of patch `i`: where it deposits [Ihrke07 sec 5.2.2].
    #[inline]
    pub fn midpoint(&self, i: usize) -> DVec3 {
        let p = self.positions(i);
        (p[0] + p[1] + p[2] + p[3]) * 0.25
    }

    /// Mean direction of travel of patch `i` (unit).
    #[inline]
    pub fn direction(&self, i: usize) -> DVec3 {
        let d = (0..4)
            .map(|c| self.corner[c][i].v.normalize_or_zero())
            .sum::<DVec3>();
        d.normalize_or_zero()
    }
}

/// Area of the quadrilateral `p` (half the cross product of its diagonals,
/// exact for a planar quad and the natural measure of a slightly warped one).
#[inline]
pub fn area(p: &[DVec3; 4]) -> f64 {
    0.5 * (p[2] - p[0]).cross(p[3] - p[1]).length()
}

/// Oriented normal of the quadrilateral `p` (not normalized): it points
/// along the direction of travel for a well-formed patch and flips when the
/// patch passes through a caustic.
#[inline]
pub fn normal(p: &[DVec3; 4]) -> DVec3 {
    (p[2] - p[0]).cross(p[3] - p[1])
}

/// Longest edge of the quadrilateral `p`: how far apart its corners are.
#[inline]
pub fn span(p: &[DVec3; 4]) -> f64 {
    let mut m: f64 = 0.0;
    for (a, b) in [(0, 1), (1, 2), (2, 3), (3, 0)] {
        m = m.max((p[a] - p[b]).length_squared());
    }
    m.sqrt()
}

/// The bilinear point of the patch at parameters `(s, t)` in [0, 1]^2,
/// corner 0 at (0, 0), 1 at (1, 0), 2 at (1, 1), 3 at (0, 1).
#[inline]
pub fn bilinear(c: &[RayState; 4], s: f64, t: f64) -> RayState {
    let w = [(1.0 - s) * (1.0 - t), s * (1.0 - t), s * t, (1.0 - s) * t];
    let mut out = RayState {
        x: DVec3::ZERO,
        v: DVec3::ZERO,
        opl: 0.0,
    };
    for (ci, wi) in c.iter().zip(w) {
        out.x += ci.x * wi;
        out.v += ci.v * wi;
        out.opl += ci.opl * wi;
    }
    out
}

/// How a patch is tessellated into four.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Split {
    /// Two by two quarters: the patch is about as long as it is wide.
    Quarters,
    /// Four strips across the `s` direction (corner 0 to 1), which is over
    /// twice as long as the other: a sliver stretched by astigmatic
    /// focusing is cut along its length only, rather than into ever
    /// thinner quarters (whose number would grow with the square of its
    /// length).
    StripsS,
    /// Four strips across the `t` direction (corner 0 to 3).
    StripsT,
}

impl Split {
    /// The split suited to the quadrilateral `p`.
    pub fn of(p: &[DVec3; 4]) -> Split {
        let ls = (p[1] - p[0]).length().max((p[2] - p[3]).length());
        let lt = (p[3] - p[0]).length().max((p[2] - p[1]).length());
        if ls > 2.0 * lt {
            Split::StripsS
        } else if lt > 2.0 * ls {
            Split::StripsT
        } else {
            Split::Quarters
        }
    }

    /// Parameter rectangle `(s0, t0, s1, t1)` of child `part` (0..4); each
    /// child keeps the parent's corner orientation.
    pub fn rect(self, part: usize) -> (f64, f64, f64, f64) {
        let q = part as f64 * 0.25;
        match self {
            Split::Quarters => {
                let (s, t) = [(0.0, 0.0), (0.5, 0.0), (0.5, 0.5), (0.0, 0.5)][part];
                (s, t, s + 0.5, t + 0.5)
            }
            Split::StripsS => (q, 0.0, q + 0.25, 1.0),
            Split::StripsT => (0.0, q, 1.0, q + 0.25),
        }
    }

    /// Corners of child `part` of the patch with corners `c`.
    pub fn child(self, c: &[RayState; 4], part: usize) -> [RayState; 4] {
        let (s0, t0, s1, t1) = self.rect(part);
        [(s0, t0), (s1, t0), (s1, t1), (s0, t1)].map(|(s, t)| bilinear(c, s, t))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(side: f64) -> [DVec3; 4] {
        [
            DVec3::ZERO,
            DVec3::new(side, 0.0, 0.0),
            DVec3::new(side, side, 0.0),
            DVec3::new(0.0, side, 0.0),
        ]
    }

    #[test]
    fn square_measures() {
        let p = square(2.0);
        assert_eq!(area(&p), 4.0);
        assert_eq!(normal(&p), DVec3::new(0.0, 0.0, 8.0));
        assert_eq!(span(&p), 2.0);
        // Mirrored corner order flips the orientation (a caustic).
        let q = [p[0], p[3], p[2], p[1]];
        assert!(normal(&q).z < 0.0);
    }

    #[test]
    fn every_split_tiles_the_patch() {
        for (w, h, want) in [
            (1.0, 1.0, Split::Quarters),
            (5.0, 1.0, Split::StripsS),
            (1.0, 3.0, Split::StripsT),
        ] {
            let c = [
                DVec3::ZERO,
                DVec3::new(w, 0.0, 0.0),
                DVec3::new(w, h, 0.0),
                DVec3::new(0.0, h, 0.0),
            ]
            .map(|x| RayState {
                x,
                v: DVec3::Z,
                opl: 0.0,
            });
            let split = Split::of(&c.map(|r| r.x));
            assert_eq!(split, want);
            let total: f64 = (0..4)
                .map(|part| {
                    let q = split.child(&c, part).map(|r| r.x);
                    assert!(normal(&q).z > 0.0);
                    area(&q)
                })
                .sum();
            assert!((total - w * h).abs() < 1e-12);
        }
    }
}
