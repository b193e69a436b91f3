// The march through the voxel grid (`render.rs`), for scenes without sharp
// interfaces; `march_stub.wgsl` stands in for it in theirs.

// March one eye ray through index channel ch from x0, where it enters the
// grid, along d; the RGB radiance it gathers.
fn march(x0: vec3<f32>, d: vec3<f32>, ch: u32) -> vec3<f32> {
    let h = P.grid.voxel;
    let ds = P.step;
    var w: Walk;
    w.x = x0;
    w.v = d * index_field(x0).x;
    w.radiance = vec3<f32>(0.0);
    w.alpha = vec3<f32>(1.0);
    w.steps = 0u;
    w.mirrored = false;
    w.has_incident = false;
    w.n_eye = index_field(P.eye).x;
    let budget = P.budget;
    let skip_empty = P.skip_empty != 0u;
    while w.steps < budget {
        let dir = normalize_or_zero(w.v);
        // Distance to the bounds: the slab test only within two steps.
        let clearance = min3(min(w.x - P.grid.min, P.grid.max - w.x));
        var exit = INF;
        if !(clearance > 2.0 * ds) {
            let c = grid_clip_line(P.grid, w.x, dir);
            exit = select(0.0, max(c.t1, 0.0), c.hit);
        }
        if exit <= 0.0 || is_zero(dir) {
            break;
        }
        if max3(w.alpha) < P.min_transmittance {
            return w.radiance;
        }
        // A straight step across clear space or a uniform block, or
        // else one step of the ray equation.
        var moved = false;
        if skip_empty {
            // A skip may be longer than two steps: it must still end at the
            // bounds (render.rs `skip_exit`).
            if exit == INF {
                let c = grid_clip_line(P.grid, w.x, dir);
                exit = select(0.0, max(c.t1, 0.0), c.hit);
            }
            let s = clear_step(ch, w.x);
            if s >= 0.0 {
                // Clear of anything that bends, scatters, emits or reflects
                // for s: one straight step in the local constant medium.
                let t = min(s, exit);
                let n = index_field(w.x).x;
                let sigma = tri_sum(propa, grid_trilinear(P.grid, w.x)).xyz;
                let tr = receiver_hit(w.x, dir, t);
                if tr >= 0.0 {
                    w.alpha *= exp(-sigma * tr);
                    w.radiance += w.alpha * receiver_radiance(w.x + dir * tr, dir, ch);
                    return w.radiance;
                }
                w.alpha *= exp(-sigma * t);
                w.x += dir * t;
                w.v = dir * n;
                w.mirrored = false;
                w.has_incident = false;
                n_skips = bump(n_skips);
                moved = true;
            }
            if !moved {
                let c = crossing(ch, w.x, dir);
                if c.ok {
                    // Just past the block's face, so that the next lookup
                    // lands in the next block: 1e-6 voxels on the CPU, at
                    // least 8 ulps of the position in f32 (less would not
                    // move the ray off the face).
                    let t = min(c.t + max(1e-6 * h, 1e-6 * max3(abs(w.x))), exit);
                    let tr = receiver_hit(w.x, dir, t);
                    if tr >= 0.0 {
                        w.alpha *= exp(-c.sigma * tr);
                        w.radiance += w.alpha * receiver_radiance(w.x + dir * tr, dir, ch);
                        return w.radiance;
                    }
                    w.alpha *= exp(-c.sigma * t);
                    w.x += dir * t;
                    if t < exit {
                        // Past the face for certain: x + d t rounds to
                        // either side of it in f32, and a ray left on the
                        // face would cross this block again, with a step of
                        // nothing. A few ulps of the scene's scale along
                        // the face's axis, never backwards.
                        let a = c.axis;
                        let eps = 2e-6 * (h + max(max3(abs(P.grid.min)), max3(abs(P.grid.max))));
                        if dir[a] > 0.0 {
                            w.x[a] = max(w.x[a], c.face + eps);
                        } else {
                            w.x[a] = min(w.x[a], c.face - eps);
                        }
                    }
                    w.v = dir * c.n;
                    w.mirrored = false;
                    w.has_incident = false;
                    n_skips = bump(n_skips);
                    moved = true;
                }
            }
        }
        if !moved {
            let stp = min(ds, max(exit, 1e-6 * h));
            let xs = w.x;
            let f = index_field(xs);
            gather(xs, f.x, f.yzw, dir, stp, ch, &w);
            // [Ihrke07 eqs 9-12] from the sample already taken.
            var inc = ray_euler_sampled(f.x, f.yzw, w.v, stp);
            if P.integrator != INTEGRATOR_EULER {
                let k0 = ray_rhs(FORM_EQUAL_DISTANCE, f.x, f.yzw, w.v);
                inc = ray_increment(FORM_EQUAL_DISTANCE, P.integrator, xs, w.v, k0, stp);
            }
            w.x += inc.x;
            w.v += inc.v;
            w.steps += 1u;
            n_steps = bump(n_steps);
            let hit = receiver_on_chord(xs, w.x);
            if hit.w >= 0.0 {
                w.radiance += w.alpha * receiver_radiance(xs + hit.xyz * hit.w, hit.xyz, ch);
                return w.radiance;
            }
        }
    }
    if w.steps >= budget {
        return w.radiance;
    }
    let dir = normalize_or_zero(w.v);
    w.radiance += w.alpha * surroundings(w.x, dir, ch);
    return w.radiance;
}
