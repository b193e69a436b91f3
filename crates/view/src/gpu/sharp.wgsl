// The eye-ray march with sharp interfaces (render.rs `march_sharp`,
// region.rs), appended to `render.wgsl` when the scene has them (`mod.rs`);
// other scenes get the stubs of `sharp_stub.wgsl`, so that their kernel
// does not carry this code. Needs: the `region` module.

// The regions (region.rs `gpu_regions`): the objects in precedence order,
// then the ambient medium.
@group(0) @binding(20) var<storage, read> regions: array<RegionGpu>;
// Their shapes' data (region.rs `GpuRegions::data`): profiles, mesh
// triangles and BVH nodes.
@group(0) @binding(21) var<storage, read> region_data: array<vec4<u32>>;

// The `region` module's hooks.
fn region_count() -> u32 {
    return P.region_count;
}

fn region_object(i: u32) -> RegionGpu {
    return regions[i];
}

// The `surface` module's hook.
fn surface_data(i: u32) -> vec4<u32> {
    return region_data[i];
}

// `index_field` in region `field_region`: its own profile.
fn sharp_index(p: vec3<f32>) -> vec4<f32> {
    return region_index(field_region, p, channel);
}

// ---- The march with sharp interfaces (render.rs `march_sharp`) ----

// A ray with sharp interfaces (region.rs `SharpRay`).
struct SharpRay {
    x: vec3<f32>,
    v: vec3<f32>,
    region: u32,
}

// One step of the ray equation in the equal-distance form from (x, v) over
// `field_region`'s profile: the increment.
fn sharp_take(x: vec3<f32>, v: vec3<f32>, h: f32) -> RayDeriv {
    let k0 = ray_deriv(FORM_EQUAL_DISTANCE, x, v);
    return ray_increment(FORM_EQUAL_DISTANCE, P.integrator, x, v, k0, h);
}

// region.rs `Step`.
struct SharpStep {
    used: f32,
    at_surface: bool,
    c: RegionCross,
}

// region.rs `Regions::step` (equal distance): advance by at most h within
// the ray's region, stopping at the first surface and crossing it there. A
// region of constant index is crossed straight; elsewhere one step of the
// integrator on the region's profile is cut where it meets a surface (by
// bisection on the step length, where the CPU takes false position).
//
// Each shared function that tests every shape (`region_next_surface`,
// `region_cross`, `region_shape_distance`) is called from one place only:
// drivers inline every call, and a copy per call site of the shapes' code
// (BVH traversals, marches) made the kernel too large to compile in time.
fn sharp_step(ray: ptr<function, SharpRay>, h: f32, ch: u32) -> SharpStep {
    let eps = P.sharp_eps;
    var out: SharpStep;
    out.used = h;
    out.at_surface = false;
    out.c.event = false;
    let r = (*ray).region;
    let x0 = (*ray).x;
    let uniform = region_uniform(r);
    // Straight: along d for h; curved: the chord of one integrator step on
    // the region's own profile (on its eikonal shell).
    let n = region_index(r, x0, ch).x;
    let d = normalize_or_zero((*ray).v);
    var v0 = d * n;
    var full = RayDeriv(d * h, vec3<f32>(0.0), 0.0);
    if !uniform {
        field_region = r;
        v0 = ray_onto_shell((*ray).v, n);
        full = sharp_take(x0, v0, h);
    }
    let chord = full.x;
    let len = length(chord);
    var dir = d;
    var reach = h;
    if !uniform {
        dir = chord / max(len, 1e-30);
        reach = len;
    }
    var hit = RegionHit(false, 0u, 0.0, vec3<f32>(0.0));
    if uniform || len > 0.0 {
        hit = region_next_surface(x0, dir, eps, reach);
    }
    if !hit.ok {
        (*ray).x = x0 + full.x;
        (*ray).v = select(v0 + full.v, d * n, uniform);
        field_region = NONE;
        return out;
    }
    var at_x = x0 + dir * hit.t;
    var at_v = v0;
    var b = hit.t;
    var normal = hit.normal;
    if !uniform {
        // Cut the step where its end lies on the surface: the object's
        // signed distance changes sign between the start's side and the
        // far one. Evaluation 0 is the side at the chord's middle, 1 the
        // step's end, then bisection on the step length.
        let obj = region_object(hit.obj);
        var side = 1.0;
        var a = 0.0;
        b = h;
        at_x = x0 + full.x;
        at_v = v0 + full.v;
        var m = 0.0;
        var inc = full;
        for (var k = 0u; k < 50u; k++) {
            var xq = at_x;
            if k == 0u {
                xq = x0 + dir * (0.5 * hit.t);
            } else if k >= 2u {
                m = 0.5 * (a + b);
                if b - a <= eps || m <= a || m >= b {
                    break;
                }
                inc = sharp_take(x0, v0, m);
                xq = x0 + inc.x;
            }
            let dq = region_shape_distance(obj, xq);
            if k == 0u {
                side = select(1.0, -1.0, dq < 0.0);
            } else if k == 1u {
                if side * dq > 0.0 {
                    // The end is back on the start's side: cut at the
                    // chord's crossing.
                    b = h * (hit.t / len);
                    let cut = sharp_take(x0, v0, b);
                    at_x = x0 + cut.x;
                    at_v = v0 + cut.v;
                }
            } else if side * dq > 0.0 {
                a = m;
            } else {
                b = m;
                at_x = xq;
                at_v = v0 + inc.v;
            }
        }
        normal = region_shape_normal(obj, at_x);
    }
    field_region = NONE;
    out.c = region_cross(r, at_v, at_x, normal, eps, ch);
    if !out.c.event && !uniform {
        // As `Regions::step` on the CPU: a false crossing or a graze that
        // turns back changes nothing, so the whole step stands, in the
        // region where it ends.
        (*ray).x = x0 + full.x;
        (*ray).v = v0 + full.v;
        (*ray).region = region_owner((*ray).x);
        return out;
    }
    (*ray).x = at_x;
    (*ray).v = out.c.v;
    (*ray).region = out.c.region;
    out.used = b;
    out.at_surface = true;
    return out;
}

// render.rs `march_sharp`: region by region, each region's own material,
// straight from surface to surface where the index is constant and nothing
// along the way scatters or emits, Fresnel at every true crossing.
fn march_sharp(o: vec3<f32>, d: vec3<f32>, ch: u32) -> vec3<f32> {
    channel = ch;
    let clip = grid_clip_line(P.grid, o, d);
    if !clip.hit || clip.t1 <= 0.0 {
        return surroundings(o, d, ch);
    }
    let t0 = max(clip.t0, 0.0);
    let tr0 = receiver_hit(o, d, t0);
    if tr0 >= 0.0 {
        return receiver_radiance(o + d * tr0, d, ch);
    }
    let ds = P.step;
    var ray: SharpRay;
    ray.x = o + d * t0;
    ray.region = region_owner(ray.x);
    ray.v = d * region_index(ray.region, ray.x, ch).x;
    var w: Walk;
    w.radiance = vec3<f32>(0.0);
    w.alpha = vec3<f32>(1.0);
    w.steps = 0u;
    w.mirrored = false;
    w.has_incident = false;
    w.n_eye = region_index(region_owner(P.eye), P.eye, ch).x;
    let lit = PASS.lit != 0u;
    var count = 0u;
    while count < P.budget {
        let dir = normalize_or_zero(ray.v);
        let c = grid_clip_line(P.grid, ray.x, dir);
        let exit = select(0.0, max(c.t1, 0.0), c.hit);
        if exit <= 0.0 || is_zero(dir) {
            break;
        }
        if max3(w.alpha) < P.min_transmittance {
            return w.radiance;
        }
        let x0 = ray.x;
        let m = region_object(ray.region);
        let sigma = region_extinction(ray.region, x0);
        let scatter = m.albedo * sigma;
        // Long straight steps where nothing needs gathering on the way:
        // a constant index with no scattering (or no light) and no
        // emission, and an extinction that is one constant.
        let quiet = region_uniform(ray.region) && (is_zero(scatter) || !lit) && is_zero(m.emission) && m.ext_volume == NO_VOLUME;
        var stp = min(ds, exit);
        if quiet {
            stp = exit;
        }
        let n = region_index(ray.region, x0, ch).x;
        let st = sharp_step(&ray, stp, ch);
        count += 1u;
        if quiet {
            n_skips = bump(n_skips);
        } else {
            n_steps = bump(n_steps);
        }
        let t = grid_trilinear(P.grid, x0);
        let emission = select(vec3<f32>(0.0), m.emission, PASS.base != 0u);
        let chord = ray.x - x0;
        let len = length(chord);
        if len > 0.0 {
            let u = chord / len;
            let tr = receiver_hit(x0, u, len);
            if tr >= 0.0 {
                absorb_and_emit(t, sigma, emission, scatter, m.g, n, u, tr, ch, &w);
                w.radiance += w.alpha * receiver_radiance(x0 + u * tr, u, ch);
                return w.radiance;
            }
        }
        absorb_and_emit(t, sigma, emission, scatter, m.g, n, dir, st.used, ch, &w);
        if st.c.event && !st.c.total {
            let rho = st.c.reflectance;
            if rho > 0.0 {
                let mirror = fresnel_reflect(st.c.incident, st.c.normal);
                w.radiance += w.alpha * surroundings(ray.x, mirror, ch) * rho;
                w.alpha *= 1.0 - rho;
            }
        }
        if !st.at_surface && stp >= exit {
            break;
        }
        if !grid_contains(P.grid, ray.x) {
            break;
        }
    }
    if count >= P.budget {
        return w.radiance;
    }
    w.radiance += w.alpha * surroundings(ray.x, normalize_or_zero(ray.v), ch);
    return w.radiance;
}

