// Fresnel reflection at a dielectric interface, unpolarized (`fresnel.rs`;
// the factors rho and tau of [Ihrke07 eqs 2, 5]).

// `fresnel::reflectance`: light arriving in n1 at an interface to n2 with
// incidence cosine cos_in (sign ignored); 1 under total internal
// reflection, 0 without a jump.
fn fresnel_reflectance(cos_in: f32, n1: f32, n2: f32) -> f32 {
    if n1 == n2 {
        return 0.0;
    }
    let cos_i = min(abs(cos_in), 1.0);
    let sin_i2 = max(1.0 - cos_i * cos_i, 0.0);
    let eta = n1 / n2;
    let sin_t2 = eta * eta * sin_i2;
    if sin_t2 >= 1.0 {
        return 1.0;
    }
    let cos_t = sqrt(1.0 - sin_t2);
    let rs = (n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t);
    let rp = (n2 * cos_i - n1 * cos_t) / (n2 * cos_i + n1 * cos_t);
    return 0.5 * (rs * rs + rp * rp);
}

// `fresnel::refract`: Snell's law for the unit d entering n2 from n1
// through a unit normal of either orientation; zero under total internal
// reflection.
fn fresnel_refract(d: vec3<f32>, normal: vec3<f32>, n1: f32, n2: f32) -> vec3<f32> {
    var n = normal;
    if dot(d, normal) > 0.0 {
        n = -normal;
    }
    let cos_i = min(-dot(d, n), 1.0);
    let eta = n1 / n2;
    let k = 1.0 - eta * eta * (1.0 - cos_i * cos_i);
    if k < 0.0 {
        return vec3<f32>(0.0);
    }
    return normalize(eta * d + (eta * cos_i - sqrt(k)) * n);
}

// `fresnel::reflect`: the mirror direction of d about the plane of normal n.
fn fresnel_reflect(d: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    return d - 2.0 * dot(d, n) * n;
}

// `fresnel::patch_transmittance`: the transmittance averaged over a patch
// whose corners (in order around it) meet the interface at c[k] =
// (cos_i, n1, n2), cos^2 and the indices bilinear between them, by 4 x 4
// Gauss-Legendre points (`fresnel::GAUSS4`).
fn fresnel_patch_transmittance(c: array<vec3<f32>, 4>) -> f32 {
    let x = array<f32, 4>(0.06943184420297371, 0.33000947820757187, 0.6699905217924281, 0.9305681557970263);
    let w = array<f32, 4>(0.17392742256872693, 0.32607257743127307, 0.32607257743127307, 0.17392742256872693);
    var q: array<vec3<f32>, 4>;
    for (var k = 0u; k < 4u; k++) {
        q[k] = vec3<f32>(c[k].x * c[k].x, c[k].y, c[k].z);
    }
    var sum = 0.0;
    for (var j = 0u; j < 4u; j++) {
        let t = x[j];
        for (var i = 0u; i < 4u; i++) {
            let s = x[i];
            let m = q[0] * ((1.0 - s) * (1.0 - t)) + q[1] * (s * (1.0 - t)) + q[2] * (s * t) + q[3] * ((1.0 - s) * t);
            sum += w[i] * w[j] * (1.0 - fresnel_reflectance(sqrt(max(m.x, 0.0)), m.y, m.z));
        }
    }
    return sum;
}
