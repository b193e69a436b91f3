//! Steps 1 and 2 of a simulation step: move every corner with the
//! equal-time ray equation (eqs 14-15), attenuate the flux along the way
//! (eq 18), then recompute each patch's differential irradiance from its
//! new area (eq 17). Corners are kept on the eikonal shell `|v| = n`
//! (`ray::step_rk4_on_shell`), which makes equal time equal optical path.
//!
//! # The attenuation integral
//! Eq 18's `int sigma_t / n dt` is taken along the patch's central path,
//! one step at a time, by the trapezoid rule: `sigma_t / n` is sampled at
//! the patch midpoint before and after the step (sigma_t trilinearly from
//! the extinction volume, n from the index field), averaged, and multiplied
//! by the step's `dt`. Since `dt = n ds` this is `int sigma_t ds`, the
//! optical depth. Outside the volume bounds sigma_t is zero, and a step
//! that crosses the bounds is charged for its part inside only
//! (`step_depth`).

use crate::patch::{area, Patches};
use eikon_grid::ray::{step_euler_on_shell, step_rk4_on_shell};
use eikon_grid::{
    EmptySpace, Form, GridGeometry, IndexField, Medium, Method, RayState, VoxelField,
};
use glam::DVec3;
use rayon::prelude::*;

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

/// Eq 18's optical depth `int sigma_t / n dt` over one step of `dt` from
/// `x0` to `x1`, given `sigma_t / n` at both ends (zero outside the
/// bounds): the trapezoid rule, except that a step crossing the bounds is
/// charged only for its part inside, at the inside end's value. (The
/// trapezoid would charge half the step whatever its part inside: up to
/// `sigma_t h / 4` too much or too little for light entering obliquely.)
pub(crate) fn step_depth(
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

/// Advance every patch by one equal-time step `dt` (optical path, world
/// units) and attenuate its flux. `absorbed` receives, per patch, the RGB
/// flux taken out of the beam in this step (absorbed or scattered away).
pub fn propagate(
    patches: &mut Patches,
    medium: &Medium,
    field: &Bounded,
    empty: &EmptySpace,
    method: Method,
    dt: f64,
    absorbed: &mut Vec<[f64; 3]>,
) {
    absorbed.clear();
    absorbed.resize(patches.len(), [0.0; 3]);
    let [c0, c1, c2, c3] = &mut patches.corner;
    (
        c0.par_iter_mut(),
        c1.par_iter_mut(),
        c2.par_iter_mut(),
        c3.par_iter_mut(),
        patches.flux.par_iter_mut(),
        absorbed.par_iter_mut(),
    )
        .into_par_iter()
        .for_each(|(a, b, c, d, flux, lost)| {
            let mid = |s: [&RayState; 4]| (s[0].x + s[1].x + s[2].x + s[3].x) * 0.25;
            // Skip empty space: with every corner and the midpoint in an
            // empty block the step (under a cell long) is a straight line
            // in a constant index without loss, taken without sampling.
            let m0 = mid([a, b, c, d]);
            if let Some(n) = empty.index_at(m0) {
                if [&*a, &*b, &*c, &*d]
                    .iter()
                    .all(|s| empty.index_at(s.x) == Some(n))
                {
                    for s in [&mut *a, &mut *b, &mut *c, &mut *d] {
                        s.v = s.v.normalize_or_zero() * n;
                        s.x += s.v * (dt / (n * n));
                        s.opl += dt;
                    }
                    *lost = [0.0; 3];
                    return;
                }
            }
            let before = extinction_per_index(medium, field, empty, m0);
            for s in [&mut *a, &mut *b, &mut *c, &mut *d] {
                // On the shell |v| = n, so each corner advances exactly dt
                // of optical path and the four stay on one wavefront.
                match method {
                    Method::Euler => step_euler_on_shell(field, Form::EqualTime, s, dt),
                    _ => step_rk4_on_shell(field, Form::EqualTime, s, dt),
                }
            }
            let m1 = mid([a, b, c, d]);
            let after = extinction_per_index(medium, field, empty, m1);
            let depth = step_depth(&medium.geometry, m0, m1, before, after, dt);
            for ch in 0..3 {
                let kept = flux[ch] * (-depth[ch]).exp();
                lost[ch] = flux[ch] - kept;
                flux[ch] = kept;
            }
        });
}

/// Eq 17 with eq 18's attenuation already in the flux: the differential
/// irradiance of each patch is its flux over its current area.
pub fn irradiance(patches: &mut Patches) {
    let [c0, c1, c2, c3] = &patches.corner;
    (
        patches.irradiance.par_iter_mut(),
        patches.flux.par_iter(),
        c0.par_iter(),
        c1.par_iter(),
        c2.par_iter(),
        c3.par_iter(),
    )
        .into_par_iter()
        .for_each(|(e, f, a, b, c, d)| {
            let ar = area(&[a.x, b.x, c.x, d.x]);
            *e = f.map(|x| if ar > 0.0 { x / ar } else { 0.0 });
        });
}

#[cfg(test)]
mod tests {
    use super::*;

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
