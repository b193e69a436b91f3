// Wyman, "Interactive Refractions and Caustics Using Image-Space
// Techniques" (ShaderX5, 2006): two-interface refraction in image space,
// as three render passes over one view (the eye's or a light's):
//
//   back_fs     back faces (front faces culled, the farthest kept: depth
//               test GREATER): outward normal N2 and view distance
//   front_fs    front faces (back faces culled, the nearest kept): the
//               G-buffer p1, d_N, N1 and p1's view distance
//   refract_fs  a full-screen triangle: per front pixel refract at N1,
//               estimate the distance to the back [Wyman06 eq 6.3.1], fetch
//               N2 where p2 projects, refract again; the exit ray
//
// The mesh is pulled from a storage buffer (three corners per triangle:
// position and d_N, then the shading normal). Fresnel and Snell are the
// shared `fresnel` module's. Generated ahead of this source: `ViewUniform`
// (the block `view`), the exit status bits (COVERED, FALLBACK_NORMAL,
// TIR_BACK, TIR_FRONT, NO_BACK_DEPTH: the w of the exit position; 0 where
// no refractor is) and the total internal reflection fills (TIR_*).

@group(0) @binding(0) var<uniform> view: ViewUniform;
@group(0) @binding(1) var<storage, read> corners: array<vec4<f32>>;
@group(0) @binding(2) var back_tex: texture_2d<f32>;
@group(0) @binding(3) var front_position: texture_2d<f32>;
@group(0) @binding(4) var front_normal: texture_2d<f32>;

// ---------------------------------------------------------------------
// The view.

fn view_dist(p: vec3<f32>) -> f32 {
    if (view.perspective != 0u) {
        return length(p - view.eye);
    }
    return dot(p - view.eye, view.forward);
}

fn view_dir(p: vec3<f32>) -> vec3<f32> {
    if (view.perspective != 0u) {
        return normalize(p - view.eye);
    }
    return view.forward;
}

// Whether a normal texel holds a surface (cleared to zero).
fn holds(n: vec4<f32>) -> bool {
    return dot(n.xyz, n.xyz) > 0.25;
}

// ---------------------------------------------------------------------
// Passes 1 and 2: the surface.

struct Surface {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) d_n: f32,
};

@vertex
fn surface_vs(@builtin(vertex_index) i: u32) -> Surface {
    let a = corners[2u * i];
    let b = corners[2u * i + 1u];
    var out: Surface;
    out.clip = view.view_proj * vec4<f32>(a.xyz, 1.0);
    out.world = a.xyz;
    out.normal = b.xyz;
    out.d_n = a.w;
    return out;
}

// Pass 1: the back surface's outward normal N2 and view distance.
@fragment
fn back_fs(s: Surface) -> @location(0) vec4<f32> {
    return vec4<f32>(normalize(s.normal), view_dist(s.world));
}

struct Front {
    @location(0) position: vec4<f32>,
    @location(1) normal: vec4<f32>,
};

// Pass 2: the front surface: p1 with d_N, and N1 with p1's view distance.
// A shading normal turned away from the viewer (at a silhouette) gives way
// to the geometric normal.
@fragment
fn front_fs(s: Surface) -> Front {
    let g = cross(dpdx(s.world), dpdy(s.world));
    let v = view_dir(s.world);
    var n = normalize(s.normal);
    if (dot(n, v) >= 0.0) {
        if (dot(g, g) > 0.0) {
            n = normalize(g);
            if (dot(n, v) > 0.0) {
                n = -n;
            }
        } else {
            n = -v;
        }
    }
    var out: Front;
    out.position = vec4<f32>(s.world, s.d_n);
    out.normal = vec4<f32>(n, view_dist(s.world));
    return out;
}

// ---------------------------------------------------------------------
// Pass 3: refraction, per front pixel.

@vertex
fn fullscreen_vs(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    // One triangle covering the target.
    let x = f32(i32(i & 1u) * 4 - 1);
    let y = f32(i32(i >> 1u) * 4 - 1);
    return vec4<f32>(x, y, 0.5, 1.0);
}

struct Exit {
    // xyz: where the ray leaves the refractor (p2); w: status bits.
    @location(0) position: vec4<f32>,
    // xyz: unit exit direction (T2); w: Fresnel transmittance of both
    // interfaces, (1 - R1)(1 - R2) (1 - R1 under total internal reflection).
    @location(1) direction: vec4<f32>,
};

// The two-interface exit of a front pixel: p1, d_N, N1 at `px`.
fn exit_ray(px: vec2<i32>) -> Exit {
    var out: Exit;
    out.position = vec4<f32>(0.0);
    out.direction = vec4<f32>(0.0);
    let f1 = textureLoad(front_normal, px, 0);
    if (!holds(f1)) {
        return out;
    }
    let f0 = textureLoad(front_position, px, 0);
    let p1 = f0.xyz;
    let d_n = f0.w;
    let n1v = f1.xyz;
    let v = view_dir(p1);
    let n_out = view.n_outside;
    let n_in = view.n_inside;
    var status = COVERED;
    // Steps 1-3: refract at the front surface.
    let r1 = fresnel_reflectance(dot(v, n1v), n_out, n_in);
    let t1 = fresnel_refract(v, n1v, n_out, n_in);
    if (dot(t1, t1) == 0.0) {
        out.position = vec4<f32>(p1, f32(status | TIR_FRONT));
        return out;
    }
    // Step 4: d_V between the front and back surfaces along the view ray,
    // d_N along the inward normal, interpolated by the angles of incidence
    // and refraction [Wyman06 eq 6.3.1]; at normal incidence the ratio's
    // limit, sin(theta_t) / sin(theta_i) = n_out / n_in.
    let b = textureLoad(back_tex, px, 0);
    var d_v = 0.0;
    if (holds(b)) {
        d_v = max(b.w - f1.w, 0.0);
    } else {
        status = status | NO_BACK_DEPTH;
    }
    let theta_i = acos(clamp(abs(dot(v, n1v)), 0.0, 1.0));
    let theta_t = acos(clamp(abs(dot(t1, n1v)), 0.0, 1.0));
    var w = n_out / n_in;
    if (theta_i > 1e-3) {
        w = theta_t / theta_i;
    }
    let d = w * d_v + (1.0 - w) * d_n;
    let p2 = p1 + d * t1;
    // Step 5: N2 from the back-face normals where p2 projects; where none
    // is there, the normal perpendicular to the view [Wyman06 eq 6.3.2].
    var n2v = vec3<f32>(0.0);
    let c = view.view_proj * vec4<f32>(p2, 1.0);
    if (c.w > 0.0) {
        let q = vec2<f32>((c.x / c.w + 1.0) * 0.5 * view.size.x, (1.0 - c.y / c.w) * 0.5 * view.size.y);
        if (q.x >= 0.0 && q.y >= 0.0 && q.x < view.size.x && q.y < view.size.y) {
            let bq = textureLoad(back_tex, vec2<i32>(floor(q)), 0);
            if (holds(bq)) {
                n2v = bq.xyz;
            }
        }
    }
    if (dot(n2v, n2v) == 0.0) {
        status = status | FALLBACK_NORMAL;
        n2v = t1 - dot(v, t1) * v;
        if (dot(n2v, n2v) < 1e-12) {
            n2v = v;
        }
        n2v = normalize(n2v);
    }
    // Step 6: refract at the back surface.
    let r2 = fresnel_reflectance(dot(t1, n2v), n_in, n_out);
    var t2 = fresnel_refract(t1, n2v, n_in, n_out);
    var tau = (1.0 - r1) * (1.0 - r2);
    if (dot(t2, t2) == 0.0) {
        // Total internal reflection: the paper's three ways to fill it.
        status = status | TIR_BACK;
        tau = 1.0 - r1;
        if (view.tir == TIR_SINGLE) {
            // Degenerate to one refraction: T2 = T1.
            t2 = t1;
        } else if (view.tir == TIR_CLAMP) {
            // Clamp to the critical angle: leave along the surface.
            let tangential = t1 - dot(t1, n2v) * n2v;
            if (dot(tangential, tangential) > 1e-12) {
                t2 = normalize(tangential);
            } else {
                t2 = t1;
            }
        } else {
            // Reflect, and ignore further interactions.
            t2 = normalize(fresnel_reflect(t1, n2v));
        }
    }
    out.position = vec4<f32>(p2, f32(status));
    out.direction = vec4<f32>(t2, tau);
    return out;
}

@fragment
fn refract_fs(@builtin(position) frag: vec4<f32>) -> Exit {
    return exit_ray(vec2<i32>(floor(frag.xy)));
}
