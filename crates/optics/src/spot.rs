//! A spot light's cone: the weight of each direction, one definition for
//! the light simulation (emission, the unobstructed irradiance a patch is
//! compared with) and the view renderer (direct light on the receiver).
//! [`WGSL`] is its twin for both GPU kernels.

use eikon_shader::{nothing, Module};
use glam::DVec3;

/// The WGSL of [`cone_weight`] (a spot light's cone, given).
pub static WGSL: Module = Module {
    name: "spot",
    requires: &[],
    declarations: nothing,
    text: include_str!("spot.wgsl"),
};

/// Spot weight of direction `dir`: 1 inside the cone, a smoothstep across
/// the `falloff` band at its edge, 0 outside. `cone` is the unit axis, the
/// half-angle and the falloff in degrees, or `None` for a point light.
pub fn cone_weight(dir: DVec3, cone: Option<(DVec3, f64, f64)>) -> f64 {
    let Some((axis, angle, falloff)) = cone else {
        return 1.0;
    };
    let theta = dir.dot(axis).clamp(-1.0, 1.0).acos().to_degrees();
    if theta >= angle {
        0.0
    } else if falloff <= 0.0 || theta <= angle - falloff {
        1.0
    } else {
        let x = (angle - theta) / falloff;
        x * x * (3.0 - 2.0 * x)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_inside_zero_outside_and_a_smoothstep_between() {
        let axis = DVec3::Z;
        let at = |deg: f64| {
            let t = deg.to_radians();
            DVec3::new(t.sin(), 0.0, t.cos())
        };
        let cone = Some((axis, 30.0, 10.0));
        assert_eq!(cone_weight(at(0.0), cone), 1.0);
        assert_eq!(cone_weight(at(19.0), cone), 1.0);
        assert_eq!(cone_weight(at(31.0), cone), 0.0);
        assert_eq!(cone_weight(-axis, cone), 0.0);
        // Halfway across the band: the smoothstep's midpoint.
        assert!((cone_weight(at(25.0), cone) - 0.5).abs() < 1e-9);
        // A quarter in from the edge: 3x^2 - 2x^3 at x = 1/4.
        let w = cone_weight(at(27.5), cone);
        assert!((w - 0.15625).abs() < 1e-9, "{w}");
        // No falloff: a hard edge; no cone: a point light.
        assert_eq!(cone_weight(at(29.9), Some((axis, 30.0, 0.0))), 1.0);
        assert_eq!(cone_weight(-axis, None), 1.0);
    }
}
