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
