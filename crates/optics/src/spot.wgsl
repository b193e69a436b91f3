// A spot light's cone (`spot::cone_weight`).

// 1 inside the cone of half-angle `angle` (degrees) about the unit `axis`,
// a smoothstep across the `falloff` band at its edge, 0 outside.
fn spot_cone_weight(dir: vec3<f32>, axis: vec3<f32>, angle: f32, falloff: f32) -> f32 {
    let theta = degrees(acos(clamp(dot(dir, axis), -1.0, 1.0)));
    if theta >= angle {
        return 0.0;
    }
    if falloff <= 0.0 || theta <= angle - falloff {
        return 1.0;
    }
    let x = (angle - theta) / falloff;
    return x * x * (3.0 - 2.0 * x);
}
