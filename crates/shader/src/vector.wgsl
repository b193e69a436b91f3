// Vector helpers (glam's, which WGSL lacks).

// `DVec3::normalize_or_zero`: the unit vector, or zero for a zero or
// non-finite length.
fn normalize_or_zero(v: vec3<f32>) -> vec3<f32> {
    let len = length(v);
    if len > 0.0 && len < 3.0e38 {
        return v / len;
    }
    return vec3<f32>(0.0);
}

fn max3(v: vec3<f32>) -> f32 {
    return max(v.x, max(v.y, v.z));
}

fn min3(v: vec3<f32>) -> f32 {
    return min(v.x, min(v.y, v.z));
}

fn is_zero(v: vec3<f32>) -> bool {
    return all(v == vec3<f32>(0.0));
}
