// The Henyey-Greenstein phase function (`phase.rs`) [Ihrke07 eqs 3, 6].
//
// Needs: the `vector` module (PI); G_MAX (generated).

// `phase::hg`: cos_theta between the light's direction of travel and the
// direction towards the eye; g clamped to [-G_MAX, G_MAX].
fn hg(cos_theta: f32, g_in: f32) -> f32 {
    let c = clamp(cos_theta, -1.0, 1.0);
    let g = clamp(g_in, -G_MAX, G_MAX);
    let g2 = g * g;
    let denom = 1.0 + g2 - 2.0 * g * c;
    return (1.0 - g2) / (4.0 * PI * denom * sqrt(denom));
}
