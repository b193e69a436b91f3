// [Ihrke07 eq 18]'s optical depth over one step (`propagate::step_depth`),
// and the per-corner weights of a patch straddling a surface
// (`propagate::straddle_weights`).
//
// Needs: the `grid` module.

// The trapezoid rule over the step of dt from x0 to x1, given sigma_t / n
// at both ends (zero outside the bounds); a step crossing the bounds is
// charged only for its part inside, at the inside end's value.
fn step_depth(g: GridGpu, x0: vec3<f32>, x1: vec3<f32>, before: vec3<f32>, after: vec3<f32>, dt: f32) -> vec3<f32> {
    let in0 = grid_contains(g, x0);
    let in1 = grid_contains(g, x1);
    if in0 == in1 {
        return (before + after) * (0.5 * dt);
    }
    let c = grid_clip_line(g, x0, x1 - x0);
    var inside = 0.0;
    if c.hit {
        inside = max(min(c.t1, 1.0) - max(c.t0, 0.0), 0.0);
    }
    return select(after, before, in0) * (dt * inside);
}

// Per corner, the share of a straddling patch's light about it before and
// after its path bends in a step (`propagate::straddle_weights`).
struct StraddleWeights {
    before: vec4<f32>,
    after: vec4<f32>,
}

// `propagate::straddle_weights`: `codes`, each corner's region as the step
// began (`propagate::region_code`: region_owner + 1); `into` and `kept`,
// the crossing as the step began (`Crossing`); `passed`, each corner's
// transmittance over the step's crossings (1 without Fresnel).
fn straddle_weights(codes: vec4<u32>, into: u32, kept: f32, passed: vec4<f32>) -> StraddleWeights {
    var before = vec4<f32>(1.0);
    if into != 0u && kept < 1.0 {
        let beyond = codes == vec4<u32>(into);
        let one = select(vec4<u32>(0u), vec4<u32>(1u), beyond);
        let m = one.x + one.y + one.z + one.w;
        if m > 0u {
            before = select(before, vec4<f32>(pow(kept, 4.0 / f32(m))), beyond);
        }
    }
    return StraddleWeights(before, before * passed);
}
