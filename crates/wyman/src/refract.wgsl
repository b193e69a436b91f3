// Wyman, "Interactive Refractions and Caustics Using Image-Space
// Techniques" (ShaderX5, 2006): two-interface refraction in image space,
// as three render passes over one view (the eye's or a light's):
//
//   back_fs     back faces (front faces culled, the farthest kept: depth
//               test GREATER): outward normal N2 and view distance
//   front_fs    front faces (back faces culled, the nearest kept): the
//               G-buffer p1, d_N, N1 and p1's view distance
//   refract_fs  a full-screen triangle: per front pixel refract at N1,
//               estimate the distance to the back [Wyman eq 6.3.1], fetch
//               N2 where p2 projects, refract again; the exit ray
//
// The mesh is pulled from a storage buffer (three corners per triangle:
// position and d_N, then the shading normal). Fresnel and Snell mirror
// eikon_grid::fresnel (a parity test holds them to it).

struct View {
    view_proj: mat4x4<f32>,
    // xyz: the eye (perspective) or a point behind the scene on the axis
    // (orthographic); w: 1 perspective, 0 orthographic.
    eye: vec4<f32>,
    // xyz: unit view axis.
    forward: vec4<f32>,
    // x, y: target size in pixels.
    size: vec4<f32>,
    // x: index outside, y: index inside, z: what total internal reflection
    // at the back does (0 single refraction, 1 clamp to the critical angle,
    // 2 reflect).
    media: vec4<f32>,
};

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var<storage, read> corners: array<vec4<f32>>;
@group(0) @binding(2) var back_tex: texture_2d<f32>;
@group(0) @binding(3) var front_position: texture_2d<f32>;
@group(0) @binding(4) var front_normal: texture_2d<f32>;

// Exit status bits (the w of the exit position; 0: no refractor here).
const COVERED: u32 = 1u;
const FALLBACK_NORMAL: u32 = 2u;  // no back normal where p2 projects: eq 6.3.2
const TIR_BACK: u32 = 4u;         // total internal reflection at the back
const TIR_FRONT: u32 = 8u;        // nothing enters (index inside < outside)
const NO_BACK_DEPTH: u32 = 16u;   // no back face at this pixel: d_V = 0

// ---------------------------------------------------------------------
// Fresnel and Snell for unpolarized light (eikon_grid::fresnel).

// Reflectance of light coming from index n1 into n2 at incidence cosine
// cos_in (sign ignored); 1 under total internal reflection.
fn reflectance(cos_in: f32, n1: f32, n2: f32) -> f32 {
    if (n1 == n2) {
        return 0.0;
    }
    let c = min(abs(cos_in), 1.0);
    let eta = n1 / n2;
    let sin_t2 = eta * eta * max(1.0 - c * c, 0.0);
    if (sin_t2 >= 1.0) {
        return 1.0;
    }
    let ct = sqrt(1.0 - sin_t2);
    let rs = (n1 * c - n2 * ct) / (n1 * c + n2 * ct);
    let rp = (n2 * c - n1 * ct) / (n2 * c + n1 * ct);
    return 0.5 * (rs * rs + rp * rp);
}

// Snell's law for the unit d through a unit normal of either orientation;
// zero under total internal reflection.
fn refracted(d: vec3<f32>, normal: vec3<f32>, n1: f32, n2: f32) -> vec3<f32> {
    var n = normal;
    if (dot(d, normal) > 0.0) {
        n = -normal;
    }
    let cos_i = min(-dot(d, n), 1.0);
    let eta = n1 / n2;
    let k = 1.0 - eta * eta * (1.0 - cos_i * cos_i);
    if (k < 0.0) {
        return vec3<f32>(0.0);
    }
    return normalize(eta * d + (eta * cos_i - sqrt(k)) * n);
}

fn reflected(d: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    return d - 2.0 * dot(d, n) * n;
}

// ---------------------------------------------------------------------
// The view.

fn view_dist(p: vec3<f32>) -> f32 {
    if (view.eye.w > 0.5) {
        return length(p - view.eye.xyz);
    }
    return dot(p - view.eye.xyz, view.forward.xyz);
}

fn view_dir(p: vec3<f32>) -> vec3<f32> {
    if (view.eye.w > 0.5) {
        return normalize(p - view.eye.xyz);
    }
    return view.forward.xyz;
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
    let n_out = view.media.x;
    let n_in = view.media.y;
    var status = COVERED;
    // Steps 1-3: refract at the front surface.
    let r1 = reflectance(dot(v, n1v), n_out, n_in);
    let t1 = refracted(v, n1v, n_out, n_in);
    if (dot(t1, t1) == 0.0) {
        out.position = vec4<f32>(p1, f32(status | TIR_FRONT));
        return out;
    }
    // Step 4: d_V between the front and back surfaces along the view ray,
    // d_N along the inward normal, interpolated by the angles of incidence
    // and refraction [Wyman eq 6.3.1]; at normal incidence the ratio's
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
    // is there, the normal perpendicular to the view [Wyman eq 6.3.2].
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
    let r2 = reflectance(dot(t1, n2v), n_in, n_out);
    var t2 = refracted(t1, n2v, n_in, n_out);
    var tau = (1.0 - r1) * (1.0 - r2);
    if (dot(t2, t2) == 0.0) {
        // Total internal reflection: the paper's three ways to fill it.
        status = status | TIR_BACK;
        tau = 1.0 - r1;
        let policy = u32(view.media.z);
        if (policy == 0u) {
            // Degenerate to one refraction: T2 = T1.
            t2 = t1;
        } else if (policy == 1u) {
            // Clamp to the critical angle: leave along the surface.
            let tangential = t1 - dot(t1, n2v) * n2v;
            if (dot(tangential, tangential) > 1e-12) {
                t2 = normalize(tangential);
            } else {
                t2 = t1;
            }
        } else {
            // Reflect, and ignore further interactions.
            t2 = normalize(reflected(t1, n2v));
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

// ---------------------------------------------------------------------
// The parity probe: Fresnel and Snell of the rows of `probe_in` (d, then
// the normal with n1 and n2 in its w... see fresnel_probe in gpu.rs),
// one pixel per case, for the test that holds them to eikon_grid::fresnel.

@group(0) @binding(5) var<storage, read> probe_in: array<vec4<f32>>;

struct Probe {
    @location(0) refracted: vec4<f32>,
    @location(1) reflected: vec4<f32>,
};

@fragment
fn probe_fs(@builtin(position) frag: vec4<f32>) -> Probe {
    let i = u32(frag.x);
    let d = probe_in[3u * i].xyz;
    let n = probe_in[3u * i + 1u].xyz;
    let ix = probe_in[3u * i + 2u];
    var out: Probe;
    out.refracted = vec4<f32>(refracted(d, n, ix.x, ix.y), reflectance(dot(d, n), ix.x, ix.y));
    out.reflected = vec4<f32>(reflected(d, n), 0.0);
    return out;
}
