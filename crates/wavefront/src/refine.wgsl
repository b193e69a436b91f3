// The tessellation analysis's light tests (`refine::below`,
// `refine::Incident::at`).

// Whether flux is below k times the irradiance `incident` in every channel
// the light carries (`refine::below`).
fn below(flux: vec3<f32>, k: f32, incident: vec3<f32>) -> bool {
    return all((incident <= vec3<f32>(0.0)) | (flux < k * incident));
}

// A point light's unobstructed irradiance at x (`refine::Incident::at`):
// its power per channel over 4 pi r^2, weighted by a spot's cone where
// `spot` (about the unit `axis`, half-angle and falloff in degrees).
fn point_irradiance(x: vec3<f32>, position: vec3<f32>, power: vec3<f32>, spot: bool, axis: vec3<f32>, angle: f32, falloff: f32) -> vec3<f32> {
    let d = x - position;
    let r2 = dot(d, d);
    var w = 1.0;
    if spot {
        w = spot_cone_weight(d / sqrt(r2), axis, angle, falloff);
    }
    return power * (w / (4.0 * PI * r2));
}
