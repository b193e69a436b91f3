// [Ihrke07 eq 18]'s optical depth over one step (`propagate::step_depth`).
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
