//! The renderer with sharp interfaces (`[grid] interfaces = "sharp"`)
//! against geometry and Fresnel computed here independently: the
//! silhouette of a glass sphere, and the reflection of a glass wall one
//! voxel thick.
//!
//! `cargo test --release -p eikon-view --test sharp -- --nocapture` prints
//! the measured figures beside those of the smoothed interfaces.

use eikon_grid::{Medium, Scene};
use eikon_optics::Image;
use eikon_testkit::scenes::camera;
use eikon_view::background::load_environment;
use eikon_view::{Options, Renderer, Surroundings};
use glam::DVec3;

fn render(scene: &Scene, sharp: bool) -> Image {
    let medium = Medium::build(scene).expect("test scene voxelizes");
    let env = load_environment(&scene.background).unwrap();
    let s = Surroundings::new(scene, env, &[], &medium.geometry);
    let cam = camera(scene);
    let mut r = Renderer::new(&medium, &[], &s, &cam, Options::default());
    if sharp {
        r = r.sharp(scene);
    }
    r.render(&|_, _| {}).0
}

/// Unpolarized Fresnel reflectance from the textbook amplitudes (Born &
/// Wolf), written out here rather than taken from `eikon-optics`.
fn fresnel(cos_i: f64, n1: f64, n2: f64) -> f64 {
    let sin_t = n1 / n2 * (1.0 - cos_i * cos_i).sqrt();
    if sin_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin_t * sin_t).sqrt();
    let rs = (n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t);
    let rp = (n2 * cos_i - n1 * cos_t) / (n2 * cos_i + n1 * cos_t);
    0.5 * (rs * rs + rp * rp)
}

/// An opaque glass sphere (n = 1.5, extinction so high that even a grazing
/// chord is black) in front of a white sky: a pixel centre that meets the
/// sphere shows only its Fresnel reflection R of the sky, one that misses
/// shows 1. The pixels darker than 0.75 (R < 0.75 up to about 88 degrees
/// of incidence) are counted in the render and, for the same camera rays,
/// with an exact ray-sphere test here; the silhouette radius `sqrt(count /
/// pi)` must agree to half a pixel at 128^3.
#[test]
fn the_silhouette_of_a_glass_sphere_is_exact() {
    const TOL_PX: f64 = 0.5;
    let c = DVec3::new(0.0, 0.0, 0.0);
    let r = 0.5;
    let text = |mode: &str| {
        format!(
            r#"
[grid]
resolution = 128
min = [-1, -1, -1]
max = [1, 1, 1]
interfaces = "{mode}"

[[object]]
name = "ball"
shape = {{ type = "sphere", center = [{}, {}, {}], radius = {r} }}
index = 1.5
extinction = [1e5, 1e5, 1e5]

[camera]
position = [0.0, 0.3, 3.0]
target = [0.0, 0.0, 0.0]
fov = 24
resolution = [200, 200]

[background]
type = "constant"
color = [1, 1, 1]
"#,
            c.x, c.y, c.z
        )
    };
    let sharp = Scene::parse(&text("sharp"), "silhouette").unwrap();
    let cam = camera(&sharp);
    let voxel = sharp.grid.geometry.voxel_size();
    // The exact count: pixel centres' rays (one sample, as rendered).
    let mut exact = 0usize;
    let (w, h) = (cam.width(), cam.height());
    for y in 0..h {
        for x in 0..w {
            let (o, d) = cam.ray(x, y, 0, Options::default().seed);
            let oc = o - c;
            let b = oc.dot(d);
            let disc = b * b - (oc.length_squared() - r * r);
            if disc > 0.0 {
                let t = -b - disc.sqrt();
                let normal = (o + d * t - c) / r;
                if fresnel(-d.dot(normal), 1.0, 1.5) < 0.75 {
                    exact += 1;
                }
            }
        }
    }
    let radius = |img: &Image| {
        let n = img.data.iter().filter(|p| p[1] < 0.75).count();
        (n as f64 / std::f64::consts::PI).sqrt()
    };
    let want = (exact as f64 / std::f64::consts::PI).sqrt();
    let got = radius(&render(&sharp, true));
    let smoothed = radius(&render(
        &Scene::parse(&text("smoothed"), "silhouette").unwrap(),
        false,
    ));
    // Pixels per voxel at the sphere's distance, to read the shifts in voxels.
    let focal = 0.5 * h as f64 / (0.5 * 24f64.to_radians()).tan();
    let px_per_voxel = focal * voxel / (cam.position() - c).length();
    println!(
        "silhouette radius: exact {want:.3} px, sharp {got:.3} px ({:+.3} px), smoothed {smoothed:.3} px ({:+.3} px = {:+.2} voxel)",
        got - want,
        smoothed - want,
        (smoothed - want) / px_per_voxel
    );
    assert!(
        (got - want).abs() <= TOL_PX,
        "sharp silhouette radius {got} px, exact {want} px"
    );
}

/// A glass wall one voxel thick (n = 1.5), seen at 30 degrees: each of its
/// two faces reflects the white plane behind the camera with Fresnel's R
/// (the same R at both, by reciprocity), and everything transmitted goes
/// into black. The eye sees `R + (1 - R) R`, which must hold to 1%.
#[test]
fn a_wall_one_voxel_thick_reflects_at_both_faces() {
    const TOL_REL: f64 = 0.01;
    let text = |mode: &str| {
        format!(
            r#"
[grid]
resolution = 128
min = [-1, -1, -1]
max = [1, 1, 1]
interfaces = "{mode}"

[[object]]
name = "wall"
shape = {{ type = "box", center = [0, 0, 0], size = [1.6, 1.6, 0.015625] }}
index = 1.5

[camera]
position = [0.0, 1.5, 2.598076211353316]
target = [0.0, 0.0, 0.0]
fov = 4
resolution = [9, 9]

[background]
type = "checker"
point = [0, 0, 6]
normal = [0, 0, -1]
square = 100
colors = [[1, 1, 1], [1, 1, 1]]
"#
        )
    };
    let r = fresnel(30f64.to_radians().cos(), 1.0, 1.5);
    let want = r + (1.0 - r) * r;
    let mean =
        |img: &Image| img.data.iter().map(|p| p[1] as f64).sum::<f64>() / img.data.len() as f64;
    let sharp = mean(&render(
        &Scene::parse(&text("sharp"), "wall").unwrap(),
        true,
    ));
    let smoothed = mean(&render(
        &Scene::parse(&text("smoothed"), "wall").unwrap(),
        false,
    ));
    println!(
        "one-voxel wall at 30 deg: R + (1 - R) R = {want:.5}; sharp {sharp:.5} ({:+.2}%), smoothed {smoothed:.5} ({:+.2}%)",
        100.0 * (sharp / want - 1.0),
        100.0 * (smoothed / want - 1.0)
    );
    assert!(
        (sharp / want - 1.0).abs() <= TOL_REL,
        "sharp wall reflects {sharp}, want {want}"
    );
}
