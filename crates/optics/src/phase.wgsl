// The Henyey-Greenstein phase function (`phase.rs`) [Ihrke07 eqs 3, 6].
//
// Needs: the `vector` module (PI); G_MAX (generated).

// `phase::hg`: cos_theta between the light's direction of travel and the
// direction towards the eye; g clamped to [-G_MAX, G_MAX]. The
// denominator's 1 + g^2 - 2 g c is written without its cancellation at the
// peak (c = sign g, |g| near 1), which f32 would round to zero there:
// (1 - |g|)^2 + 2 |g| (1 - c sign g).
fn hg(cos_theta: f32, g_in: f32) -> f32 {
    let c = clamp(cos_theta, -1.0, 1.0);
    let g = clamp(g_in, -G_MAX, G_MAX);
    let a = abs(g);
    let denom = (1.0 - a) * (1.0 - a) + 2.0 * a * (1.0 - c * sign(g));
    return (1.0 - g * g) / (4.0 * PI * denom * sqrt(denom));
}
