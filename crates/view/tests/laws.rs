//! The view renderer's laws, each one body run on every backend
//! (`NAME::cpu`, `NAME::gpu`; the GPU's are reported as ignored without an
//! adapter, and fail under `CI`, which has lavapipe): an empty volume shows
//! the environment along every eye ray, and a glass slab seen face on
//! transmits Fresnel's `(1 - R)^2`. f32 tolerances are stated where they
//! differ. Measured numbers are printed (`--nocapture`).

use eikon_testkit::scenes::{camera, lit};
use eikon_testkit::{Backend, Tests};
use eikon_view::background::load_environment;
use eikon_view::{Options, Surroundings};

/// Each pixel of an empty volume is the sky looked up along its ray, with
/// and without empty-space skipping (the GPU's f32 lookups of the sun's
/// steep lobe: measured worst relative difference 1.6e-4).
fn an_empty_volume_shows_the_environment(b: &Backend) {
    let (scene, medium, volumes) = lit(r#"
[grid]
resolution = 24
min = [-1, -1, -1]
max = [1, 1, 1]

[camera]
position = [0.3, 0.4, 3.0]
target = [0, 0, 0]
fov = 60
resolution = [48, 36]

[background]
type = "sky"
"#);
    let env = load_environment(&scene.background).unwrap();
    let s = Surroundings::new(&scene, env.clone(), &volumes, &medium.geometry);
    let cam = camera(&scene);
    for skip in [true, false] {
        let opts = Options {
            skip_empty: skip,
            seed: 7,
            ..Options::default()
        };
        let (img, _) = b.render(&medium, &volumes, &s, &cam, opts);
        let mut worst: f64 = 0.0;
        for y in 0..cam.height() {
            for x in 0..cam.width() {
                let (_, d) = cam.ray(x, y, 0, 7);
                let want = env.lookup(d);
                let got = img.pixel(x, y).unwrap();
                for c in 0..3 {
                    worst = worst.max((got[c] as f64 - want[c]).abs() / want[c].max(1e-3));
                }
            }
        }
        println!(
            "empty volume ({}), skip {skip}: worst relative difference {worst:.2e}",
            b.name()
        );
        assert!(worst <= b.pick(1e-5, 1e-3), "{worst}");
    }
}

/// A glass slab (n = 1.5) seen face on against a uniform board behind it:
/// the board's radiance times the Fresnel transmission of both faces,
/// `(1 - R)^2` with `R = ((n1 - n2) / (n1 + n2))^2` at normal incidence;
/// without the slab the board is seen unchanged.
fn normal_incidence_transmits_the_fresnel_fraction(b: &Backend) {
    let text = r#"
[grid]
resolution = 48
min = [-1, -1, -1]
max = [1, 1, 1]

[[object]]
shape = { type = "box", center = [0, 0, 0], size = [3, 3, 0.8] }
index = 1.5

[camera]
position = [0, 0, 40]
target = [0, 0, 0]
fov = 0.5
resolution = [5, 5]

[background]
type = "checker"
point = [-50, -50, -3]
normal = [0, 0, 1]
square = 100
colors = [[1, 1, 1], [1, 1, 1]]
"#;
    let render = |text: &str| {
        let (scene, medium, volumes) = lit(text);
        let env = load_environment(&scene.background).unwrap();
        let s = Surroundings::new(&scene, env, &volumes, &medium.geometry);
        b.render(&medium, &volumes, &s, &camera(&scene), Options::default())
            .0
    };
    let img = render(text);
    let r = ((1.0f64 - 1.5) / (1.0 + 1.5)).powi(2);
    let want = (1.0 - r) * (1.0 - r);
    let got = img.pixel(2, 2).unwrap()[1] as f64;
    println!(
        "slab at normal incidence ({}): transmitted {got:.5}, (1 - R)^2 = {want:.5}",
        b.name()
    );
    assert!((got - want).abs() < 1e-3, "{got} vs {want}");
    let bare = render(&text.replace("index = 1.5", "index = 1.0"));
    let got = bare.pixel(2, 2).unwrap()[1] as f64;
    assert!((got - 1.0).abs() < b.pick(1e-6, 1e-5), "{got}");
}

fn main() {
    Tests::new()
        .both(
            "an_empty_volume_shows_the_environment",
            an_empty_volume_shows_the_environment,
        )
        .both(
            "normal_incidence_transmits_the_fresnel_fraction",
            normal_incidence_transmits_the_fresnel_fraction,
        )
        .run()
}
