//! The exact mesh-boundary renderers behind `eikon render --method
//! walter|holzschuch|straight`: a scene's mesh object becomes an
//! `eikon_exact::single::MeshMedium` (homogeneous inside, clear outside),
//! its lights point or directional lights, and the image is single
//! scattering computed through the refracting boundary (Walter et al.
//! 2009, Holzschuch 2015) or with straight shadow rays.

use anyhow::{bail, Context, Result};
use eikon_exact::single::{self, MeshLight, MeshMedium, Method, Settings, Stats};
use eikon_exact::walter::Mode;
use eikon_grid::{IndexProfile, Light, Scene, Shape};
use eikon_optics::{Camera, Image};
use glam::DVec3;

/// The scene's one mesh object as a homogeneous medium in a clear ambient.
pub fn mesh_medium(scene: &Scene) -> Result<MeshMedium> {
    let meshes: Vec<usize> = (0..scene.objects.len())
        .filter(|&i| matches!(scene.objects[i].shape, Shape::Mesh(_)))
        .collect();
    let err = |field: &str, msg: String| anyhow::Error::new(scene.error_at(field, msg));
    let Some(&i) = meshes.first() else {
        return Err(err(
            "object",
            "the exact methods (walter, holzschuch, straight) need an object whose shape is a mesh (type = \"mesh\", \"bumpy_sphere\" or \"cuboctahedron\")".into(),
        ));
    };
    if scene.objects.len() > 1 {
        return Err(err(
            &format!("object[{}]", if i == 0 { 1 } else { 0 }),
            format!(
                "the exact methods render one mesh-bounded medium; this scene has {} objects (use --method eikonal)",
                scene.objects.len()
            ),
        ));
    }
    let amb = &scene.ambient;
    let outside = match amb.index {
        IndexProfile::Constant(n) if n[0] == n[1] && n[1] == n[2] => n[0],
        _ => {
            return Err(err(
                "ambient.index",
                "the exact methods need one constant ambient index".into(),
            ))
        }
    };
    if amb.extinction != DVec3::ZERO || amb.extinction_grid.is_some() {
        return Err(err(
            "ambient.extinction",
            "the exact methods need a clear ambient medium (extinction 0)".into(),
        ));
    }
    let o = &scene.objects[i];
    let m = &o.material;
    let at = |k: &str| format!("object[{i}].{k}");
    let inside = match m.index {
        IndexProfile::Constant(n) if n[0] == n[1] && n[1] == n[2] && m.index_grid.is_none() => n[0],
        IndexProfile::Constant(_) => {
            return Err(err(
                &at("index"),
                "the exact methods take one index; dispersion needs --method eikonal".into(),
            ))
        }
        _ => return Err(err(
            &at("index"),
            "the exact methods need a homogeneous medium; a graded index needs --method eikonal"
                .into(),
        )),
    };
    if m.extinction_grid.is_some() {
        return Err(err(
            &at("extinction"),
            "the exact methods need a constant extinction".into(),
        ));
    }
    let Shape::Mesh(solid) = &o.shape else {
        unreachable!("filtered above")
    };
    let medium = MeshMedium::new(
        (**solid.mesh()).clone(),
        inside / outside,
        m.extinction,
        m.albedo,
        m.g,
    )
    .map_err(|e| err(&at("shape"), e.to_string()))?;
    Ok(if solid.smooth() {
        medium
    } else {
        medium.faceted()
    })
}

/// The scene's lights for the exact methods.
pub fn mesh_lights(scene: &Scene) -> Result<Vec<MeshLight>> {
    scene
        .lights
        .iter()
        .enumerate()
        .map(|(i, l)| match *l {
            Light::Point { position, power } => Ok(MeshLight::Point { position, power }),
            Light::Directional { direction, power } => Ok(MeshLight::Directional {
                direction,
                irradiance: power,
            }),
            Light::Spot { .. } => Err(anyhow::Error::new(scene.error_at(
                &format!("light[{i}].type"),
                "the exact methods take point and directional lights; a spot light needs --method eikonal",
            ))),
        })
        .collect()
}

/// Points along each refracted camera segment (Walter, straight), or per
/// piece of each triangle's interval (Holzschuch).
pub fn method(name: &str, samples: Option<usize>) -> Result<Method> {
    Ok(match name {
        "walter" => Method::Walter {
            samples: samples.unwrap_or(32),
        },
        "holzschuch" => Method::Holzschuch {
            samples: samples.unwrap_or(1),
        },
        "straight" => Method::Straight {
            samples: samples.unwrap_or(32),
        },
        other => bail!("--method: no exact method {other}"),
    })
}

/// Render `scene` exactly with `method` seen by `camera`.
pub fn render(
    scene: &Scene,
    camera: &Camera,
    method: Method,
    guaranteed: bool,
    seed: u64,
) -> Result<(Image, Stats)> {
    let medium = mesh_medium(scene)?;
    let lights = mesh_lights(scene)?;
    if scene.receiver.is_some() {
        eprintln!("warning: the exact methods do not render the [receiver] plane");
    }
    let env = eikon_view::background::load_environment(&scene.background)
        .with_context(|| format!("{}: background", scene.origin))?;
    let background = move |d: DVec3| DVec3::from_array(env.lookup(d));
    let settings = Settings {
        mode: if guaranteed {
            Mode::Guaranteed
        } else {
            Mode::Heuristic
        },
        seed,
    };
    let bar = indicatif::ProgressBar::new(camera.height() as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "rendering {bar:40} {pos}/{len} rows ({elapsed}, {eta} left)",
        )
        .expect("valid template"),
    );
    let out = single::render_with(
        &medium,
        &lights,
        camera,
        &background,
        method,
        &settings,
        &|done, _| bar.set_position(done as u64),
    );
    bar.finish_and_clear();
    Ok(out)
}
