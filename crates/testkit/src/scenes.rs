//! Scenes several test files use.

use eikon_grid::{Medium, Scene};

/// Parse a scene and build its medium.
pub fn medium(text: &str) -> (Scene, Medium) {
    let scene = Scene::parse(text, "test").unwrap();
    let m = Medium::build(&scene).unwrap();
    (scene, m)
}

/// A glass sphere (n = 1.5, absorbing, scattering) in a `res`^3 grid over
/// [-1, 1]^3, under a directional, a point and a spot light; `extra` goes
/// into `[grid]`.
pub fn glass_sphere(res: usize, extra: &str) -> String {
    format!(
        r#"
[grid]
resolution = {res}
{extra}
min = [-1, -1, -1]
max = [1, 1, 1]

[[object]]
shape = {{ type = "sphere", center = [0.02, 0.1, -0.01], radius = 0.5 }}
index = 1.5
extinction = [0.3, 0.6, 0.9]
albedo = [0.5, 0.5, 0.5]

[[light]]
type = "directional"
direction = [0.2, -1.0, 0.1]
power = [1, 1, 1]

[[light]]
type = "point"
position = [0.7, 0.8, -0.6]
power = [5, 5, 5]

[[light]]
type = "spot"
position = [-1.5, 0.3, 0.2]
direction = [1, -0.2, 0]
angle = 30
falloff = 5
power = [20, 10, 5]
"#
    )
}
