// Fresnel transmission across a smoothed interface (`interface.rs`).
//
// Needs: the `fresnel` module.

// `interface::crossing_transmittance`: 1 - R crossing the interface
// between the sides `lo` and `hi` with unit `normal`, for light of eikonal
// gradient v, from Snell's invariant |v_t|; 1 under total internal
// reflection and where the sides do not differ.
fn interface_crossing_transmittance(lo: f32, hi: f32, v: vec3<f32>, normal: vec3<f32>) -> f32 {
    if !(lo > 0.0 && hi > 0.0) || lo == hi {
        return 1.0;
    }
    let vt = v - normal * dot(v, normal);
    let vt2 = dot(vt, vt);
    let n_min = min(lo, hi);
    if vt2 >= n_min * n_min {
        return 1.0;
    }
    let cos_lo = sqrt(max(1.0 - vt2 / (lo * lo), 0.0));
    return 1.0 - fresnel_reflectance(cos_lo, lo, hi);
}

// `interface::band_transmittance`: the power fraction kept
// over the displacement dx, (1 - R)^(delta |dx . normal|), where the
// boundary indicator is `delta`, the sides `lo`, `hi`, and `grad` the index
// gradient (the normal's direction).
fn interface_transmittance(lo: f32, hi: f32, delta: f32, grad: vec3<f32>, v: vec3<f32>, dx: vec3<f32>) -> f32 {
    if !(delta > 0.0) {
        return 1.0;
    }
    let len = length(grad);
    if !(len > 0.0 && len < 3.0e38) {
        return 1.0;
    }
    let normal = grad / len;
    let part = min(delta * abs(dot(dx, normal)), 1.0);
    if !(part > 0.0) {
        return 1.0;
    }
    return pow(interface_crossing_transmittance(lo, hi, v, normal), part);
}
