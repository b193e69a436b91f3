//! Wyman's image-space refraction and caustic maps on the GPU (lavapipe in
//! CI: under `CI` a missing adapter fails), against the exact Snell tracer,
//! the paper's method evaluated independently in f64 on exact spheres, and
//! the eikonal light simulation.

use eikon_exact::snell;
use eikon_gpu::Gpu;
use eikon_mesh::geodesic_sphere;
use eikon_optics::Camera;
use eikon_testkit::Tests;
use eikon_wyman::{gpu::status, Raster, Refractor, Settings, Shading, Tir, View};
use glam::{DVec2, DVec3};

/// Near and far hits of the ray `o + t d` (unit d) on the unit sphere at
/// the origin.
fn sphere_hits(o: DVec3, d: DVec3) -> Option<(f64, f64)> {
    let b = o.dot(d);
    let c = o.length_squared() - 1.0;
    let disc = b * b - c;
    (disc >= 0.0).then(|| (-b - disc.sqrt(), -b + disc.sqrt()))
}

/// Snell's law, `eta = n1 / n2`, a normal of either orientation.
fn refract(d: DVec3, n: DVec3, eta: f64) -> Option<DVec3> {
    let n = if d.dot(n) > 0.0 { -n } else { n };
    let c = -d.dot(n);
    let k = 1.0 - eta * eta * (1.0 - c * c);
    (k >= 0.0).then(|| (eta * d + (eta * c - k.sqrt()) * n).normalize())
}

use eikon_optics::fresnel::reflectance;

fn angle_deg(a: DVec3, b: DVec3) -> f64 {
    a.normalize()
        .dot(b.normalize())
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees()
}

fn percentile(v: &[f64], p: f64) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s[((s.len() - 1) as f64 * p).round() as usize]
}

/// The paper's method on the exact unit sphere, in f64, for the eye ray
/// `(o, d)`: exact p1 and N1, d_V the exact chord along the view ray, d_N
/// the diameter (the inward normal runs through the centre),
/// [Wyman06 eq 6.3.1], N2 the normal where the eye ray through p2 leaves
/// the sphere ([Wyman06 eq 6.3.2] where it misses), total internal
/// reflection reflected. Returns the exit direction and whether TIR came in.
fn paper_on_sphere(o: DVec3, d: DVec3, n: f64) -> Option<(DVec3, bool)> {
    let (t0, t1) = sphere_hits(o, d)?;
    let p1 = o + d * t0;
    let t_1 = refract(d, p1, 1.0 / n)?;
    let th_i = d.dot(p1).abs().min(1.0).acos();
    let th_t = t_1.dot(p1).abs().min(1.0).acos();
    let w = if th_i > 1e-3 { th_t / th_i } else { 1.0 / n };
    let p2 = p1 + t_1 * (w * (t1 - t0) + (1.0 - w) * 2.0);
    let v2 = (p2 - o).normalize();
    let n2 = match sphere_hits(o, v2) {
        Some((_, far)) => o + v2 * far,
        None => (t_1 - d * d.dot(t_1)).normalize(),
    };
    Some(match refract(t_1, n2, n) {
        Some(t2) => (t2, false),
        None => (t_1 - 2.0 * t_1.dot(n2) * n2, true),
    })
}

fn sphere_exit_directions_against_snell(gpu: &Gpu) {
    // A glass sphere (geodesic, 20480 triangles, exact vertex normals),
    // radius 65 pixels in a 160 x 160 image.
    let mesh = geodesic_sphere(1.0, 32).unwrap();
    let n = 1.5;
    let refractor = Refractor::new(mesh.clone(), Shading::Smooth, n, 1.0, DVec3::ZERO).unwrap();
    let exact = snell::Scene {
        bodies: vec![snell::Body::new(mesh, n, DVec3::ZERO, 0).unwrap()],
        ambient: 1.0,
    };
    let opts = snell::Options {
        shading_normals: true,
        max_depth: 2,
        ..snell::Options::default()
    };
    let size = 160;
    let cam = Camera::new(
        DVec3::new(0.0, 0.0, 4.0),
        DVec3::ZERO,
        DVec3::Y,
        34.0,
        size,
        size,
        1,
    )
    .unwrap();
    let raster = Raster::new(gpu, &refractor).unwrap();
    let targets = raster.targets([size, size]).unwrap();
    let view = View::of_camera(&cam, DVec2::splat(0.5), DVec3::ZERO, 1.0);
    let rays = raster.exit_rays(&view, Tir::Reflect, &targets).unwrap();
    // Per covered pixel: sine of the front incidence, error against the
    // exact two-refraction exit, against the paper's method in f64, and
    // whether the GPU and the f64 method agree on total internal
    // reflection.
    let mut rows: Vec<(f64, f64, f64, bool, f64)> = Vec::new();
    let mut tir = 0;
    for y in 0..size {
        for x in 0..size {
            let Some(e) = rays.at(x, y) else { continue };
            let (o, d) = cam.center_ray(x, y);
            let path = snell::trace(&exact, o, d, &opts);
            let Some(ex) = path
                .exits
                .iter()
                .find(|x| x.reflections == 0 && x.true_hits == 2)
            else {
                continue;
            };
            let Some((model, model_tir)) = paper_on_sphere(o, d, n) else {
                continue;
            };
            let gpu_tir = e.status & status::TIR_BACK != 0;
            tir += usize::from(gpu_tir);
            let sin_i = (o + d * (-o.dot(d))).length();
            rows.push((
                sin_i,
                angle_deg(e.t2, ex.dir),
                angle_deg(e.t2, model),
                gpu_tir == model_tir,
                angle_deg(model, ex.dir),
            ));
        }
    }
    let all: Vec<f64> = rows.iter().map(|r| r.1).collect();
    println!(
        "sphere, n = 1.5: {} pixels ({} with total internal reflection at the back); error against Snell, degrees:",
        rows.len(),
        tir
    );
    for p in [0.5, 0.9, 0.95, 0.99, 1.0] {
        print!("  P{:.0} {:.3}", 100.0 * p, percentile(&all, p));
    }
    println!();
    println!("  by incidence (deg): pixels, median, P90, max against Snell; median, P99 against the paper's method in f64");
    for k in 0..10 {
        let lo = f64::from(k) / 10.0;
        let band: Vec<&(f64, f64, f64, bool, f64)> = rows
            .iter()
            .filter(|r| r.0 >= lo && r.0 < lo + 0.1)
            .collect();
        let e: Vec<f64> = band.iter().map(|r| r.1).collect();
        let m: Vec<f64> = band.iter().filter(|r| r.3).map(|r| r.2).collect();
        println!(
            "  {:>4.1}-{:>4.1}: {:>5} {:>7.3} {:>7.3} {:>7.3}; {:>6.3} {:>6.3}",
            lo.asin().to_degrees(),
            (lo + 0.1).min(1.0).asin().to_degrees(),
            e.len(),
            percentile(&e, 0.5),
            percentile(&e, 0.9),
            percentile(&e, 1.0),
            percentile(&m, 0.5),
            percentile(&m, 0.99)
        );
    }
    // The implementation is the paper's method: it agrees with the f64
    // evaluation but for the image-space quantization (the back normal
    // read from the nearest texel: half a texel is 0.44 deg of normal on
    // this sphere) and for total internal reflection flipping at the
    // boundaries between the two.
    let agree: Vec<f64> = rows.iter().filter(|r| r.3).map(|r| r.2).collect();
    let flips = rows.len() - agree.len();
    println!(
        "  against the paper's method in f64: median {:.3}, P99 {:.3} deg; {flips} pixels disagree on total internal reflection",
        percentile(&agree, 0.5),
        percentile(&agree, 0.99)
    );
    assert!(percentile(&agree, 0.5) < 0.5 && percentile(&agree, 0.99) < 3.0);
    assert!(flips * 100 < rows.len(), "{flips}");
    // The method's own error grows with the incidence ([Wyman06 eq 6.3.1]
    // drifts from the true chord). Where it is designed to work, below 45 deg
    // of incidence on this convex object with one back surface, the bound is
    // the f64 method's own worst error there plus 1 deg for the image-space
    // lookup (half a texel of back normal is 0.44 deg here); over the whole
    // sphere the median stays below 2 deg.
    let below45 = |r: &&(f64, f64, f64, bool, f64)| r.0 < 45f64.to_radians().sin();
    let gpu45 = rows.iter().filter(below45).map(|r| r.1).fold(0.0, f64::max);
    let model45 = rows.iter().filter(below45).map(|r| r.4).fold(0.0, f64::max);
    println!("  below 45 deg incidence: worst {gpu45:.3} deg; the f64 method's own worst {model45:.3} deg");
    assert!(gpu45 <= model45 + 1.0, "{gpu45} {model45}");
    assert!(percentile(&all, 0.5) < 2.0);
}

fn slab_is_exact_where_the_back_distance_is(gpu: &Gpu) {
    // A slab 0.5 thick, 3 x 3 wide, seen nearly face on: its back face is
    // parallel to the front, so the back normal read anywhere on it is the
    // exact one and the exit direction is exact whatever the distance
    // estimate; the exit point is off by exactly |d~ - d| along T1, and
    // exact where [Wyman06 eq 6.3.1] is (normal incidence).
    let half = DVec3::new(1.5, 1.5, 0.25);
    let mesh = eikon_mesh::cuboid(half).unwrap();
    let n = 1.5;
    let refractor = Refractor::new(mesh, Shading::Flat, n, 1.0, DVec3::ZERO).unwrap();
    let size = 128;
    let cam = Camera::new(
        DVec3::new(0.05, -0.03, 4.0),
        DVec3::ZERO,
        DVec3::Y,
        50.0,
        size,
        size,
        1,
    )
    .unwrap();
    let raster = Raster::new(gpu, &refractor).unwrap();
    let targets = raster.targets([size, size]).unwrap();
    let view = View::of_camera(&cam, DVec2::splat(0.5), DVec3::ZERO, half.length());
    let rays = raster.exit_rays(&view, Tir::Reflect, &targets).unwrap();
    let (mut worst_dir, mut worst_pos, mut count) = (0.0f64, 0.0f64, 0);
    let mut nearest_normal = (f64::INFINITY, f64::INFINITY);
    for y in 0..size {
        for x in 0..size {
            let (o, d) = cam.center_ray(x, y);
            let p1 = o + d * ((0.25 - o.z) / d.z);
            let t1 = refract(d, DVec3::Z, 1.0 / n).unwrap();
            let dist = 0.5 / -t1.z;
            let exit = p1 + t1 * dist;
            let Some(e) = rays.at(x, y) else {
                assert!(p1.x.abs() > 1.49 || p1.y.abs() > 1.49, "({x}, {y}) missed");
                continue;
            };
            let behind = p1 + d * (0.5 / -d.z);
            if [exit, p1, behind]
                .iter()
                .any(|p| p.x.abs() > 1.45 || p.y.abs() > 1.45)
            {
                continue; // the view or refracted ray meets a side
            }
            count += 1;
            assert_eq!(e.status, status::COVERED, "({x}, {y})");
            // [Wyman06 eq 6.3.1] evaluated here: d_V the chord along the view
            // ray, d_N the thickness.
            let th_i = (-d.z).acos();
            let th_t = (-t1.z).acos();
            let w = if th_i > 1e-3 { th_t / th_i } else { 1.0 / n };
            let d_tilde = w * 0.5 / -d.z + (1.0 - w) * 0.5;
            let pos = (e.p2 - exit).length();
            worst_dir = worst_dir.max(angle_deg(e.t2, d).to_radians());
            worst_pos = worst_pos.max((pos - (d_tilde - dist).abs()).abs());
            if th_i < nearest_normal.0 {
                nearest_normal = (th_i, pos);
            }
        }
    }
    println!(
        "slab: {count} pixels through front and back; worst exit direction error {worst_dir:.2e} rad; exit point error minus |d~ - d|: worst {worst_pos:.2e}; at {:.3} deg incidence the exit point is off by {:.2e}",
        nearest_normal.0.to_degrees(),
        nearest_normal.1
    );
    assert!(count > 5000);
    assert!(worst_dir < 1e-5, "{worst_dir}");
    assert!(worst_pos < 1e-4, "{worst_pos}");
    assert!(nearest_normal.0 < 0.5f64.to_radians() && nearest_normal.1 < 1e-4);
}

/// A scene of one sphere of index `index` over a receiver, lit by `light`.
fn sphere_scene(index: f64, light: &str) -> eikon_grid::Scene {
    let text = format!(
        r#"
[grid]
resolution = 16
min = [-1.0, -1.0, -1.0]
max = [1.0, 1.0, 1.0]

[[object]]
shape = {{ type = "sphere", center = [0.0, 0.15, 0.0], radius = 0.45 }}
index = {index}

[[light]]
{light}

[receiver]
point = [0.0, -0.9, 0.0]
normal = [0.0, 1.0, 0.0]
albedo = [0.8, 0.8, 0.8]

[camera]
position = [0.5, 0.75, 2.9]
target = [0.1, -0.3, 0.0]
resolution = [64, 48]
samples = 2
"#
    );
    eikon_grid::Scene::parse(&text, "sphere.toml").unwrap()
}

const DIRECTIONAL: &str =
    "type = \"directional\"\ndirection = [0.2, -1.0, 0.1]\npower = [1.0, 1.0, 1.0]";
const POINT: &str = "type = \"point\"\nposition = [0.3, 1.6, 0.2]\npower = [1.0, 1.0, 1.0]";

fn an_index_matched_object_neither_shadows_nor_focuses(gpu: &Gpu) {
    // Index 1 in air: every photon goes straight on, so the caustic map
    // must give back the unobstructed light behind the sphere, exactly
    // where the shadow map takes it away: the splats' weights and the
    // photons' solid angles (a point light) conserve power.
    for light in [DIRECTIONAL, POINT] {
        let scene = sphere_scene(1.0, light);
        let refractor = Refractor::from_scene(&scene).unwrap();
        let settings = Settings {
            photons: 256,
            caustic_map: 256,
            ..Settings::default()
        };
        let raster = Raster::new(gpu, &refractor).unwrap();
        let maps =
            eikon_wyman::render::caustic_maps(&raster, &scene, &refractor, &settings).unwrap();
        let map = &maps[0];
        let (c, radius) = refractor.bounding_sphere();
        let (mut worst, mut inside, mut outside) = (0.0f64, 0, 0);
        for i in -60..60 {
            for k in -60..60 {
                let x = DVec3::new(f64::from(i) * 0.02, -0.9, f64::from(k) * 0.02);
                // Where x lies relative to the sphere's outline seen from
                // the light, in caustic-map texels (a splat reaches four
                // out: three, and one of interpolation).
                let v = map.view;
                let q = v.pixel(x).unwrap() - v.pixel(c).unwrap();
                let d = (c - v.eye).length();
                let tan = if v.perspective {
                    radius / (d * d - radius * radius).sqrt()
                } else {
                    radius
                };
                let outline = tan / v.half.x * f64::from(v.size[0]) / 2.0;
                let r = q.length();
                if r < outline - 6.0 {
                    inside += 1;
                    assert!(map.visibility(x) == 0.0);
                } else if r > outline + 6.0 {
                    outside += 1;
                    assert!(
                        map.caustic(x) == DVec3::ZERO && (map.visibility(x) - 1.0).abs() < 1e-12
                    );
                } else {
                    continue;
                }
                worst = worst.max((map.factor(x) - DVec3::ONE).abs().max_element());
            }
        }
        println!(
            "{}: {inside} points behind the sphere, {outside} beside it, worst |factor - 1| {worst:.2e}",
            light.lines().next().unwrap()
        );
        assert!(inside > 500 && outside > 500);
        assert!(worst < 1e-3, "{worst}");
    }
}

fn caustic_of_a_glass_sphere_against_the_eikonal_light_simulation(gpu: &Gpu) {
    // [Ihrke07 fig 7] (configs/glass-sphere.toml) at 64^3 for the
    // eikonal light simulation (EIKON_CAUSTIC_RESOLUTION=128 for the
    // config's own, a minute more).
    let res = std::env::var("EIKON_CAUSTIC_RESOLUTION").unwrap_or_else(|_| "64".into());
    let text = include_str!("../../../configs/glass-sphere.toml")
        .replace("resolution = 128", &format!("resolution = {res}"));
    let scene = eikon_grid::Scene::parse(&text, "glass-sphere.toml").unwrap();
    let t = std::time::Instant::now();
    let medium = eikon_grid::Medium::build(&scene).unwrap();
    let (volume, _) = eikon_wavefront::simulate_light(
        &scene.lights[0],
        &medium,
        &eikon_wavefront::Options::default(),
        &|_, _| {},
    )
    .unwrap();
    println!(
        "eikonal light simulation: {:.1} s",
        t.elapsed().as_secs_f64()
    );
    let volumes = [volume];
    let env = eikon_view::background::load_environment(&scene.background).unwrap();
    let eikonal = eikon_view::Surroundings::new(&scene, env, &volumes, &medium.geometry);
    // The paper's sizes scaled down: 256^2 photons, a caustic map of half
    // their resolution over the same view (twice as many texels over twice
    // the view), 7 x 7 splats.
    let refractor = Refractor::from_scene(&scene).unwrap();
    let settings = Settings {
        photons: 256,
        caustic_map: 256,
        ..Settings::default()
    };
    let raster = Raster::new(gpu, &refractor).unwrap();
    let maps = eikon_wyman::render::caustic_maps(&raster, &scene, &refractor, &settings).unwrap();
    let receiver = scene.receiver.clone().unwrap();
    let eikon_grid::Light::Directional { direction, power } = scene.lights[0] else {
        panic!("Fig. 7 has a directional light");
    };
    let l = direction.normalize();
    let (c, radius) = (DVec3::new(0.0, 0.15, 0.0), 0.45);
    let mean = |v: DVec3| (v.x + v.y + v.z) / 3.0;
    let e0 = mean(power) * (-l.dot(receiver.normal));
    // The caustic region: the receiver behind the sphere, kept 0.15 radius
    // clear of its shadow's edge (there the eikonal volumes blur the
    // direct light in over about two voxels).
    let region = |x: DVec3| {
        let q = x - c;
        (q - l * q.dot(l)).length() < 0.85 * radius
    };
    // Irradiance sums over a 4 mm raster of the receiver.
    let h = 0.004;
    let (mut fw, mut fe, mut cw, mut ce) = (0.0, 0.0, DVec3::ZERO, DVec3::ZERO);
    for i in -200..200 {
        for k in -200..200 {
            let x = DVec3::new(
                (f64::from(i) + 0.5) * h,
                receiver.point.y,
                (f64::from(k) + 0.5) * h,
            );
            if !region(x) {
                continue;
            }
            let ew = e0 * mean(maps[0].factor(x));
            let ee = mean(eikonal.receiver_radiance(x, -DVec3::Y, 0)) * std::f64::consts::PI
                / mean(receiver.albedo);
            fw += ew * h * h;
            fe += ee * h * h;
            cw += x * ew * h * h;
            ce += x * ee * h * h;
        }
    }
    let (cw, ce) = (cw / fw, ce / fe);
    // Independently, in f64 through the exact sphere: parallel rays 1/1500
    // of its diameter apart, Fresnel and Beer-Lambert; both the exact
    // paths (two refractions, and the few with internal reflections) and
    // the paper's method ([Wyman06 eq 6.3.1], N2 read along the light where p2
    // projects, [Wyman06 eq 6.3.2] beside the sphere, TIR reflected).
    let u = l.cross(DVec3::X).normalize();
    let v = l.cross(u);
    let m = 1500;
    let da = (2.0 * radius / f64::from(m)).powi(2);
    let sigma = mean(DVec3::new(0.05, 0.03, 0.03));
    let lands = |p: DVec3, t: DVec3| {
        let s = (receiver.point.y - p.y) / t.y;
        s > 0.0 && region(p + t * s)
    };
    let (mut exact2, mut exact_more, mut paper) = (0.0, 0.0, 0.0);
    for i in 0..m {
        for k in 0..m {
            let a = (f64::from(i) + 0.5) / f64::from(m) * 2.0 - 1.0;
            let b = (f64::from(k) + 0.5) / f64::from(m) * 2.0 - 1.0;
            if a * a + b * b >= 1.0 {
                continue;
            }
            let o = c + (u * a + v * b) * radius - l * 3.0;
            let (t0, t1u) = sphere_hits((o - c) / radius, l).unwrap();
            let p1 = o + l * t0 * radius;
            let n1 = (p1 - c) / radius;
            let t1 = refract(l, n1, 1.0 / 1.5).unwrap();
            let enter = 1.0 - reflectance(l.dot(n1), 1.0, 1.5);
            // The paper's method.
            let th_i = l.dot(n1).abs().acos();
            let th_t = t1.dot(n1).abs().acos();
            let w = if th_i > 1e-3 { th_t / th_i } else { 1.0 / 1.5 };
            let dd = w * (t1u - t0) * radius + (1.0 - w) * 2.0 * radius;
            let p2 = p1 + t1 * dd;
            let n2 = match sphere_hits((p2 - c) / radius - l * 3.0, l) {
                Some((_, far)) => (p2 - c) / radius + l * (far - 3.0),
                None => (t1 - l * l.dot(t1)).normalize(),
            };
            let through = enter * (-sigma * dd).exp();
            let (t2, tau) = match refract(t1, n2, 1.5) {
                Some(t2) => (t2, through * (1.0 - reflectance(t1.dot(n2), 1.5, 1.0))),
                None => (t1 - 2.0 * t1.dot(n2) * n2, through),
            };
            if lands(p2, t2) {
                paper += tau * da * mean(power);
            }
            // Exact paths, up to five internal reflections.
            let (mut p, mut t, mut weight) = (p1, t1, enter);
            for bounce in 0..6 {
                let (_, tt) = sphere_hits((p - c) / radius, t).unwrap();
                let q = p + t * tt * radius;
                let nq = (q - c) / radius;
                weight *= (-sigma * tt * radius).exp();
                let r = reflectance(t.dot(nq), 1.5, 1.0);
                if let Some(out) = refract(t, nq, 1.5) {
                    if lands(q, out) {
                        let f = weight * (1.0 - r) * da * mean(power);
                        if bounce == 0 {
                            exact2 += f;
                        } else {
                            exact_more += f;
                        }
                    }
                }
                weight *= r;
                t = t - 2.0 * t.dot(nq) * nq;
                p = q;
            }
        }
    }
    let texel = 2.0 * radius * 1.01 * settings.caustic_extent / f64::from(settings.caustic_map);
    let off = (cw - ce).length() / texel;
    println!(
        "caustic flux over the region (W): wyman {fw:.4}, the paper's method in f64 {paper:.4} (GPU / f64 {:.4}), exact two refractions {exact2:.4} (+{exact_more:.4} after internal reflections), eikonal at {res}^3 {fe:.4}",
        fw / paper
    );
    println!(
        "  wyman / eikonal {:.3}, wyman / exact {:.3}, eikonal / exact {:.3}",
        fw / fe,
        fw / (exact2 + exact_more),
        fe / (exact2 + exact_more)
    );
    println!(
        "  centroid: wyman {:.4?}, eikonal {:.4?}: {:.2} caustic-map texels ({texel:.4}) apart",
        cw.to_array(),
        ce.to_array(),
        off
    );
    // The centroid: within 2 texels of the eikonal's.
    assert!(off < 2.0, "{off}");
    // The flux: the GPU's caustic map is the paper's method (within 2% of
    // its f64 evaluation). Against the eikonal renderer it falls short by
    // more than 10%: the method itself lands 11% less light here than the
    // exact paths do ([Wyman06 eq 6.3.1] shortens the chord through the outer
    // sphere, bending light out of the region), and the eikonal volumes
    // at 64^3 hold 15% more than the exact paths (7% at 128^3): see
    // docs/PERFORMANCE.md.
    assert!((fw / paper - 1.0).abs() < 0.02, "{}", fw / paper);
}

fn a_frame_is_the_same_whatever_the_threads_and_fits_its_estimate(gpu: &Gpu) {
    let scene = sphere_scene(1.5, DIRECTIONAL);
    let mut cs = eikon_view::render::camera_settings(&scene);
    cs.resolution = [96, 72];
    let camera = eikon_view::render::camera(&cs).unwrap();
    let settings = Settings {
        photons: 128,
        caustic_map: 128,
        ..Settings::default()
    };
    gpu.reset_peak();
    let (a, stats) = eikon_wyman::render(gpu, &scene, &camera, &settings).unwrap();
    let peak = gpu.peak_bytes();
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let (b, _) = one
        .install(|| eikon_wyman::render(gpu, &scene, &camera, &settings))
        .unwrap();
    assert!(a.data == b.data, "a frame differs between thread counts");
    // Two samples: two eye passes of three, one light of four.
    assert_eq!(stats.passes, 2 * 3 + 4);
    assert!(stats.covered > 0 && stats.caustic_lights == 1);
    let triangles = Refractor::from_scene(&scene).unwrap().mesh.triangle_count();
    let estimate = eikon_wyman::render::device_bytes(triangles, 96, 72, &settings);
    println!("device bytes: peak {peak}, estimate {estimate}");
    assert!(peak <= estimate && estimate < 2 * peak, "{peak} {estimate}");
}

fn lights_and_cameras_it_cannot_take_are_refused(gpu: &Gpu) {
    let camera = |scene: &eikon_grid::Scene| {
        eikon_view::render::camera(&eikon_view::render::camera_settings(scene)).unwrap()
    };
    let spot = sphere_scene(
        1.5,
        "type = \"spot\"\nposition = [0.0, 1.6, 0.0]\ndirection = [0.0, -1.0, 0.0]\nangle = 20.0\npower = [1.0, 1.0, 1.0]",
    );
    let e = eikon_wyman::render(gpu, &spot, &camera(&spot), &Settings::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("light[0].type") && e.contains("spot"), "{e}");
    let inside = sphere_scene(
        1.5,
        "type = \"point\"\nposition = [0.0, 0.2, 0.0]\npower = [1.0, 1.0, 1.0]",
    );
    let e = eikon_wyman::render(gpu, &inside, &camera(&inside), &Settings::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("light[0].position"), "{e}");
    let scene = sphere_scene(1.5, DIRECTIONAL);
    let mut cs = eikon_view::render::camera_settings(&scene);
    cs.position = DVec3::new(0.0, 0.2, 0.1);
    let e = eikon_wyman::render(
        gpu,
        &scene,
        &eikon_view::render::camera(&cs).unwrap(),
        &Settings::default(),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("camera.position"), "{e}");
}

fn main() {
    Tests::new()
        .gpu(
            "sphere_exit_directions_against_snell",
            sphere_exit_directions_against_snell,
        )
        .gpu(
            "slab_is_exact_where_the_back_distance_is",
            slab_is_exact_where_the_back_distance_is,
        )
        .gpu(
            "an_index_matched_object_neither_shadows_nor_focuses",
            an_index_matched_object_neither_shadows_nor_focuses,
        )
        .gpu(
            "caustic_of_a_glass_sphere_against_the_eikonal_light_simulation",
            caustic_of_a_glass_sphere_against_the_eikonal_light_simulation,
        )
        .gpu(
            "a_frame_is_the_same_whatever_the_threads_and_fits_its_estimate",
            a_frame_is_the_same_whatever_the_threads_and_fits_its_estimate,
        )
        .gpu(
            "lights_and_cameras_it_cannot_take_are_refused",
            lights_and_cameras_it_cannot_take_are_refused,
        )
        .run()
}
