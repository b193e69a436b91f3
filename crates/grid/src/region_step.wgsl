// `Regions::step` (region.rs) in either form of the ray equation: one step
// of a ray with sharp interfaces, within its region, cut at the first
// surface it meets and crossed there (Snell's law or total internal
// reflection, `region_cross`). Light corners step in the equal-time form
// (`propagate::Sharp`), eye rays in the equal-distance form.
//
// Hooks: `var<private> field_region: u32`, which the kernel's
// `index_field` (the `ray` module's hook) reads: while it is not NONE,
// `index_field` returns region `field_region`'s own profile
// (`region_index`); and the constant NONE. Needs: the `ray` and `region`
// modules.

// A ray with sharp interfaces (region.rs `SharpRay`): position, eikonal
// gradient, optical path so far and the region it is in.
struct RegionRay {
    x: vec3<f32>,
    v: vec3<f32>,
    opl: f32,
    region: u32,
}

// region.rs `Step`, with the event's surface and regions.
struct RegionStep {
    // How much of the step was used, in the form's units.
    used: f32,
    // The step stopped at a surface (a true or a false crossing).
    at_surface: bool,
    // What the crossing did (`c.event`: a true crossing).
    c: RegionCross,
    // With an event: the surface's region, the region the ray came from
    // (`Event::from`) and the one beyond the surface (`Event::to`, also
    // under total reflection, where the ray stays where it was).
    surface: u32,
    came: u32,
    beyond: u32,
}

// One step of h of the integrator from (x, v) in the current
// `field_region`: the increment.
fn region_take(form: u32, integrator: u32, x: vec3<f32>, v: vec3<f32>, h: f32) -> RayDeriv {
    let k0 = ray_deriv(form, x, v);
    return ray_increment(form, integrator, x, v, k0, h);
}

// `Regions::cross` at the end of a step that stopped on the surface of
// region `surface`: the ray's state afterwards and the step's event.
fn region_step_cross(ray: ptr<function, RegionRay>, out: ptr<function, RegionStep>, surface: u32, v: vec3<f32>, point: vec3<f32>, normal: vec3<f32>, ch: u32, eps: f32) {
    let here = (*ray).region;
    let c = region_cross(here, v, point, normal, eps, ch);
    (*out).c = c;
    (*out).surface = surface;
    (*out).came = here;
    (*out).beyond = c.region;
    if c.total {
        // `region_cross` keeps the ray in its region; the event names
        // the region beyond, as the CPU's `Event::to`.
        (*out).beyond = region_owner(point + c.normal * eps);
    }
    (*ray).x = point;
    (*ray).v = c.v;
    (*ray).region = c.region;
}

// `Regions::settle`: a ray that a step left on a surface (its length ran
// out where it crossed) moved a few eps on along its direction until the
// region its position reports is the one it is in, since the next step
// takes its region from its position and skips what lies within eps of
// its start.
fn region_settle(ray: ptr<function, RegionRay>, eps: f32) {
    let d = normalize_or_zero((*ray).v);
    var h = 2.0 * eps;
    for (var i = 0u; i < 4u; i++) {
        if region_owner((*ray).x) == (*ray).region {
            return;
        }
        (*ray).x += d * h;
        h *= 8.0;
    }
}

// `Regions::step`: advance the ray by at most h (distance in the
// equal-distance form, optical path in the equal-time form) within its
// region, stopping at the first surface it meets and crossing it there. A
// region of constant index is crossed straight; elsewhere one step of the
// integrator on the region's profile is taken and cut where it meets a
// surface (by bisection on the step length, where the CPU takes false
// position; both stop within eps). eps: the length below which two points
// on a ray are one.
//
// Each function that tests every shape (`region_next_surface`,
// `region_cross` through `region_step_cross`, `region_shape_distance`,
// `region_shape_normal`) and the integrator's step are called from one
// place only: drivers inline every call, and a copy per call site of the
// shapes' code (BVH traversals, profiles, grids) made kernels take minutes
// to compile on lavapipe.
fn region_step(ray: ptr<function, RegionRay>, form: u32, integrator: u32, h: f32, ch: u32, eps: f32) -> RegionStep {
    var out: RegionStep;
    out.used = h;
    out.at_surface = false;
    out.c.event = false;
    out.c.total = false;
    out.surface = NONE;
    out.came = (*ray).region;
    out.beyond = (*ray).region;
    let r = (*ray).region;
    let x0 = (*ray).x;
    let opl0 = (*ray).opl;
    let uniform = region_uniform(r);
    let n = region_index(r, x0, ch).x;
    let d = normalize_or_zero((*ray).v);
    // Straight: along d for the distance that uses the whole step; curved:
    // one step of the integrator on the region's own profile, from the
    // eikonal shell of its index (so that in the equal-time form every
    // step is exactly h of optical path).
    let per = select(n, 1.0, form == FORM_EQUAL_DISTANCE);
    var v0 = d * n;
    var full = RayDeriv(d * (h / per), vec3<f32>(0.0), n * (h / per));
    if !uniform {
        field_region = r;
        v0 = ray_onto_shell((*ray).v, n);
        full = region_take(form, integrator, x0, v0, h);
    }
    let len = length(full.x);
    var dir = d;
    if !uniform {
        dir = full.x / max(len, 1e-30);
    }
    var hit = RegionHit(false, 0u, 0.0, vec3<f32>(0.0));
    if len > 0.0 {
        // Straight: a surface within eps beyond the end is crossed now, as
        // `Regions::step` does (a step never ends on a surface uncrossed).
        hit = region_next_surface(x0, dir, eps, select(len, len + 2.0 * eps, uniform));
    }
    if !hit.ok {
        (*ray).x = x0 + full.x;
        (*ray).v = v0 + full.v;
        (*ray).opl = opl0 + full.opl;
        field_region = NONE;
        return out;
    }
    // Where the step meets the surface: straight, at the crossing.
    var at = RayDeriv(dir * hit.t, vec3<f32>(0.0), n * hit.t);
    var b = hit.t * per;
    var normal = hit.normal;
    if !uniform {
        // Cut the step where its end lies on the surface: the object's
        // signed distance changes sign between the start's side and the
        // far one. Evaluation 0 is the side at the chord's middle, 1 the
        // step's end; where the end is back on the start's side (the step
        // crossed the surface twice, or grazed it) the step is cut at the
        // chord's crossing; then bisection on the step length.
        let obj = region_object(hit.obj);
        var side = 1.0;
        var a = 0.0;
        b = h;
        at = full;
        var cut = false;
        var m = 0.0;
        for (var k = 0u; k < 50u; k++) {
            var xq = x0 + full.x;
            var inc = full;
            if k == 0u {
                xq = x0 + dir * (0.5 * hit.t);
            } else if k >= 2u {
                if cut {
                    m = b;
                } else {
                    m = 0.5 * (a + b);
                    if b - a <= eps || m <= a || m >= b {
                        break;
                    }
                }
                inc = region_take(form, integrator, x0, v0, m);
                xq = x0 + inc.x;
                if cut {
                    at = inc;
                    cut = false;
                    continue;
                }
            }
            let dq = region_shape_distance(obj, xq);
            if k == 0u {
                side = select(1.0, -1.0, dq < 0.0);
            } else if k == 1u {
                if side * dq > 0.0 {
                    b = h * (hit.t / len);
                    cut = true;
                }
            } else if side * dq > 0.0 {
                a = m;
            } else {
                b = m;
                at = inc;
            }
        }
        normal = region_shape_normal(obj, x0 + at.x);
    }
    field_region = NONE;
    let at_x = x0 + at.x;
    var probe = *ray;
    region_step_cross(&probe, &out, hit.obj, v0 + at.v, at_x, normal, ch, eps);
    if !out.c.event && !uniform {
        // A false crossing, or a graze that turns back into the region:
        // nothing changes there, so the whole step stands, in the region
        // where it ends (as on the CPU).
        (*ray).x = x0 + full.x;
        (*ray).v = v0 + full.v;
        (*ray).opl = opl0 + full.opl;
        (*ray).region = region_owner((*ray).x);
        return out;
    }
    *ray = probe;
    (*ray).opl = opl0 + at.opl;
    out.used = b;
    out.at_surface = true;
    return out;
}
