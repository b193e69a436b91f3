// The ray equation (`ray.rs`) in both first-order forms [Ihrke07 eq 8]:
// equal distance, dx/ds = v / n, dv/ds = grad n, dL/ds = n
// [Ihrke07 eqs 9-10], for eye rays; equal time, dx/dt = v / n^2,
// dv/dt = grad n / n, dL/dt = 1 [Ihrke07 eqs 14-15], for light. Forward
// Euler [Ihrke07 eqs 11-12] and classical RK4.
//
// Steps return their increments, not the new state: the light simulator
// keeps corners 1-3 relative to corner 0 and moves them by differences of
// increments, which the f32 rounding of absolute positions would spoil.
//
// Hook: `fn index_field(p: vec3<f32>) -> vec4<f32>`, the kernel's index n
// and its gradient (n, grad n) at p (`IndexField::sample`).
// Needs: FORM_* and INTEGRATOR_* (generated from `Form`, `Method`).

struct RayDeriv {
    x: vec3<f32>,
    v: vec3<f32>,
    opl: f32,
}

// `ray::rhs`: the right-hand side from an index sample (n, g) already taken.
fn ray_rhs(form: u32, n: f32, g: vec3<f32>, v: vec3<f32>) -> RayDeriv {
    let inv = 1.0 / n;
    if form == FORM_EQUAL_DISTANCE {
        return RayDeriv(v * inv, g, n);
    }
    return RayDeriv(v * (inv * inv), g * inv, 1.0);
}

fn ray_deriv(form: u32, x: vec3<f32>, v: vec3<f32>) -> RayDeriv {
    let s = index_field(x);
    return ray_rhs(form, s.x, s.yzw, v);
}

// What one step of size h adds to (x, v, L), given its first slope k0
// (taken at x with v): forward Euler, or classical RK4 (`ray::step_euler`,
// `ray::step_rk4`, whose `rk4_combine` sums the slopes in the same order).
fn ray_increment(form: u32, integrator: u32, x: vec3<f32>, v: vec3<f32>, k0: RayDeriv, h: f32) -> RayDeriv {
    if integrator == INTEGRATOR_EULER {
        return RayDeriv(k0.x * h, k0.v * h, k0.opl * h);
    }
    // The three later slopes from one call of `ray_deriv` in a loop:
    // drivers inline every call, and the index field (every region's
    // profile, VDB grids included) written out once per stage tripled the
    // size of every kernel that steps rays. The sums are the CPU's, in its
    // order. (On lavapipe the loop spends three of an invocation's 65535
    // loop iterations per step; see `surface.wgsl`.)
    var k1 = k0;
    var k2 = k0;
    // The slope the next stage starts from: k3 once the loop ends.
    var k3 = k0;
    for (var stage = 1u; stage < 4u; stage++) {
        let a = select(0.5 * h, h, stage == 3u);
        let k = ray_deriv(form, x + k3.x * a, v + k3.v * a);
        if stage == 1u {
            k1 = k;
        } else if stage == 2u {
            k2 = k;
        }
        k3 = k;
    }
    let w = h / 6.0;
    return RayDeriv(
        (k0.x + (k1.x + k2.x) * 2.0 + k3.x) * w,
        (k0.v + (k1.v + k2.v) * 2.0 + k3.v) * w,
        (k0.opl + 2.0 * (k1.opl + k2.opl) + k3.opl) * w,
    );
}

// `ray::step_euler_sampled`: the eye rays' equal-distance Euler step from
// the sample (n, g) already taken at x [Ihrke07 eqs 11-12].
fn ray_euler_sampled(n: f32, g: vec3<f32>, v: vec3<f32>, h: f32) -> RayDeriv {
    return RayDeriv(v * (h / n), g * h, n * h);
}

// `ray::onto_shell`: v rescaled to |v| = n, its direction kept.
fn ray_onto_shell(v: vec3<f32>, n: f32) -> vec3<f32> {
    let len = length(v);
    if len > 0.0 {
        return v * (n / len);
    }
    return v;
}

// A step that starts on the eikonal shell (`step_euler_on_shell`,
// `step_rk4_on_shell`): `v` is what the increment applies to.
struct RayStep {
    v: vec3<f32>,
    inc: RayDeriv,
}

fn ray_step_on_shell(form: u32, integrator: u32, x: vec3<f32>, v: vec3<f32>, h: f32) -> RayStep {
    let s = index_field(x);
    let v0 = ray_onto_shell(v, s.x);
    let k0 = ray_rhs(form, s.x, s.yzw, v0);
    return RayStep(v0, ray_increment(form, integrator, x, v0, k0, h));
}
