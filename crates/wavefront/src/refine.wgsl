// The tessellation analysis's light tests (`refine::below`,
// `refine::Incident::at`, `refine::faint`).

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

// The light the tessellation's tests compare with (`refine::Incident`): a
// plane wave of irradiance `power` per channel (INCIDENT_UNIFORM), or a
// point or spot light of `power` at `position` (INCIDENT_POINT,
// INCIDENT_SPOT, with its cone about the unit `axis`, half-angle and
// falloff in degrees).
struct Incident {
    kind: u32,
    power: vec3<f32>,
    position: vec3<f32>,
    axis: vec3<f32>,
    angle: f32,
    falloff: f32,
}

// The light's unobstructed irradiance per channel at x
// (`refine::Incident::at`).
fn refine_incident_at(light: Incident, x: vec3<f32>) -> vec3<f32> {
    if light.kind == INCIDENT_UNIFORM {
        return light.power;
    }
    return point_irradiance(x, light.position, light.power, light.kind == INCIDENT_SPOT, light.axis, light.angle, light.falloff);
}

// Whether a ray at x going along d has left the grid for good: outside,
// and heading away from it (`refine::gone`).
fn refine_gone(g: GridGpu, x: vec3<f32>, d: vec3<f32>) -> bool {
    let clip = grid_clip_line(g, x, d);
    return !grid_contains(g, x) && (!clip.hit || clip.t1 <= 0.0);
}

// Whether a patch with corners x moving along v, carrying `flux` and `span`
// across, is too faint to follow (`refine::faint`): its flux below `k`
// times the light's irradiance at its midpoint, `incident`; over
// `corner_rays` across, a quarter of it below that at each corner inside
// the grid, and each corner outside gone.
fn refine_faint(g: GridGpu, light: Incident, k: f32, corner_rays: f32, flux: vec3<f32>, x: array<vec3<f32>, 4>, v: array<vec3<f32>, 4>, span: f32, incident: vec3<f32>) -> bool {
    if span <= corner_rays {
        return below(flux, k, incident);
    }
    let quarter = 0.25 * flux;
    for (var c = 0u; c < 4u; c++) {
        if grid_contains(g, x[c]) {
            if !below(quarter, k, refine_incident_at(light, x[c])) {
                return false;
            }
        } else if !refine_gone(g, x[c], v[c]) {
            return false;
        }
    }
    return true;
}
