// The eye-ray march with sharp interfaces (render.rs `march_sharp`,
// region.rs), appended to `render.wgsl` when the scene has them (`mod.rs`);
// other scenes get the stubs of `sharp_stub.wgsl`, so that their kernel
// does not carry this code. Needs: the `region` and `region_step` modules.

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

// render.rs `march_sharp`: region by region, each region's own material,
// straight from surface to surface where the index is constant and nothing
// along the way scatters or emits, Fresnel at every true crossing. From x0,
// where the eye ray enters the grid, along d.
fn march_sharp(x0: vec3<f32>, d: vec3<f32>, ch: u32) -> vec3<f32> {
    let ds = P.step;
    var ray: RegionRay;
    ray.x = x0;
    ray.region = region_owner(ray.x);
    ray.v = d * region_index(ray.region, ray.x, ch).x;
    ray.opl = 0.0;
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
        // One step within the region, cut and crossed at the first
        // surface (`region_step`, the light simulation's own step).
        let st = region_step(&ray, FORM_EQUAL_DISTANCE, P.integrator, stp, ch, P.sharp_eps);
        count += 1u;
        if quiet {
            n_skips = bump(n_skips);
        } else {
            n_steps = bump(n_steps);
        }
        let t = grid_trilinear(P.grid, x0);
        let emission = select(vec3<f32>(0.0), m.emission, PASS.base != 0u);
        let hit = receiver_on_chord(x0, ray.x);
        if hit.w >= 0.0 {
            absorb_and_emit(t, sigma, emission, scatter, m.g, n, hit.xyz, hit.w, ch, &w);
            w.radiance += w.alpha * receiver_radiance(x0 + hit.xyz * hit.w, hit.xyz, ch);
            return w.radiance;
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

