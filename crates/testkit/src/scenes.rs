//! Scenes several test files use.

use eikon_grid::{Medium, Scene};
use eikon_optics::Camera;
use eikon_wavefront::{DepositRule, LightVolume, Options};

/// Parse a scene and build its medium.
pub fn medium(text: &str) -> (Scene, Medium) {
    let scene = Scene::parse(text, "test").unwrap();
    let m = Medium::build(&scene).unwrap();
    (scene, m)
}

/// Parse a scene, build its medium and simulate its lights on the CPU
/// with default options: what a render test lights its scene with.
pub fn lit(text: &str) -> (Scene, Medium, Vec<LightVolume>) {
    let (scene, medium) = medium(text);
    let volumes = scene
        .lights
        .iter()
        .map(|l| {
            eikon_wavefront::simulate_light(l, &medium, &Options::default(), &|_, _| {})
                .unwrap()
                .0
        })
        .collect();
    (scene, medium, volumes)
}

/// A point light above and to the side of the origin, a grey floor below
/// it and a camera looking at the origin from the front, `[w, h]` pixels
/// of `samples` samples: the rest of a small render test's scene after its
/// `[grid]`, `[ambient]` and objects.
pub fn point_lit_floor([w, h]: [u32; 2], samples: u32) -> String {
    format!(
        r#"
[[light]]
type = "point"
position = [0.6, 0.8, 0.3]
power = [5, 5, 5]

[receiver]
point = [0, -0.7, 0]
normal = [0, 1, 0]
albedo = [0.8, 0.8, 0.8]

[camera]
position = [0.5, 1, 3]
target = [0, 0, 0]
fov = 45
resolution = [{w}, {h}]
samples = {samples}
"#
    )
}

/// The camera of a scene's `[camera]`.
pub fn camera(scene: &Scene) -> Camera {
    eikon_view::render::camera(&eikon_view::render::camera_settings(scene)).unwrap()
}

/// The default light simulation: the track-length fluence deposit with
/// Fresnel transmission.
pub fn fluence() -> Options {
    Options::default()
}

/// The paper's deposit ([Ihrke07 sec 5.2.2], the highest-energy ray per
/// cell, patches culled at caustics) without Fresnel, as the CLI's
/// `--deposit paper --no-fresnel`.
pub fn paper() -> Options {
    Options {
        deposit: DepositRule::Paper,
        fresnel: false,
        ..Options::default()
    }
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
