//! Scene files: TOML read through serde, unknown fields rejected, every
//! value checked, and every error located by file, line, column and field.
//!
//! The format is documented field by field in `docs/SCENES.md`. This
//! module holds the checked scene and its public types; the schema serde
//! reads is `scene/raw.rs`, the checks `scene/check.rs`, the files a scene
//! names (meshes, VDB grids) `scene/assets.rs`, and the location of errors
//! `scene/locate.rs`.

mod assets;
mod check;
pub(crate) mod locate;
mod raw;

use crate::error::{Error, Result};
use crate::geometry::GridGeometry;
use crate::object::{Material, Object};
use glam::DVec3;
use locate::{deserialize, parse_path, Checker};
use raw::{default_render_step, RawResolution, RawScene};
use std::path::Path;

/// Grid settings of a scene.
#[derive(Clone, Debug)]
pub struct GridSettings {
    /// Resolution and bounds.
    pub geometry: GridGeometry,
    /// Gaussian smoothing of n before the gradient, sigma in voxels (0 = none).
    pub smoothing: f64,
    /// Sub-samples per axis in voxels a surface crosses (anti-aliasing).
    pub supersample: usize,
    /// Three index fields (R, G, B) instead of one.
    pub dispersion: bool,
    /// How rays meet the surfaces between materials: smoothed into the
    /// index field (the paper's way) or exactly ([`crate::region`]).
    pub interfaces: crate::region::Interfaces,
}

/// The largest light power accepted, per channel (W, or W/m^2 for a
/// directional light). Light volumes are stored in f32 (at most 3.4e38),
/// and light concentrates by many orders of magnitude (a point light's
/// `P / (4 pi r^2)` a voxel from it, caustics, the renderer's scattering
/// factors): 1e20 leaves room for that far beyond any physical source.
/// Whatever still overflows is an error naming the light, never an
/// infinite value written.
pub const MAX_LIGHT_POWER: f64 = 1e20;

/// The largest extinction accepted, per channel and world unit. The medium
/// stores it in f32 (at most 3.4e38), and an infinite value would poison
/// trilinear interpolation (`0 * inf`); anything this opaque already
/// transmits nothing over 1e-28 of a world unit.
pub const MAX_EXTINCTION: f64 = 1e30;

/// A light source. Power is RGB: irradiance (W/m^2) across the beam for a
/// directional light, radiant power (W) into the full sphere for a point
/// light, and the power a point light of that size would have for a spot.
#[derive(Clone, Debug)]
pub enum Light {
    /// A plane wave travelling along `direction`.
    Directional {
        /// Unit direction of travel.
        direction: DVec3,
        /// RGB irradiance on a plane normal to the beam, W/m^2.
        power: DVec3,
    },
    /// A spherical wave from `position`.
    Point {
        /// Where the light is.
        position: DVec3,
        /// RGB radiant power, W.
        power: DVec3,
    },
    /// A point light restricted to a cone.
    Spot {
        /// Where the light is.
        position: DVec3,
        /// Unit cone axis.
        direction: DVec3,
        /// Cone half-angle, degrees.
        angle: f64,
        /// Width of the soft edge inside the cone, degrees.
        falloff: f64,
        /// RGB power of the unrestricted point light, W.
        power: DVec3,
    },
}

/// A diffuse receiver plane (the table a caustic falls on).
#[derive(Clone, Debug)]
pub struct Receiver {
    /// A point on the plane.
    pub point: DVec3,
    /// Unit normal, facing the lit side.
    pub normal: DVec3,
    /// RGB diffuse reflectance.
    pub albedo: DVec3,
}

/// Where the scene is seen from: a look-at pinhole camera.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraSettings {
    /// Eye position, world units.
    pub position: DVec3,
    /// Point the camera looks at.
    pub target: DVec3,
    /// Up direction (unit; need not be orthogonal to the view direction).
    pub up: DVec3,
    /// Vertical field of view, degrees.
    pub fov: f64,
    /// Image width and height, pixels.
    pub resolution: [u32; 2],
    /// Samples per pixel (stratified).
    pub samples: u32,
}

/// What an eye ray sees once it has left the volume (and missed the
/// receiver).
#[derive(Clone, Debug, PartialEq)]
pub enum Background {
    /// One RGB radiance in every direction.
    Constant(DVec3),
    /// The built-in procedural sky (no file needed), scaled.
    Sky {
        /// Radiance scale.
        intensity: f64,
    },
    /// A lat-long HDR environment map read from an EXR file.
    Environment {
        /// The file, resolved against the scene file's folder.
        file: std::path::PathBuf,
        /// Radiance scale.
        intensity: f64,
    },
    /// An emitting checkerboard plane (black beyond it): a test pattern
    /// behind a lens.
    Checker {
        /// A point on the plane (a corner of a square).
        point: DVec3,
        /// Unit normal.
        normal: DVec3,
        /// Edge length of a square, world units.
        square: f64,
        /// RGB radiance of the two kinds of square.
        colors: [DVec3; 2],
    },
}

/// How eye rays are marched and the image exposed.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderSettings {
    /// Step length, voxels.
    pub step: f64,
    /// Integrator of the eye rays: Euler [Ihrke07 eqs 11-12] or RK4.
    pub integrator: crate::ray::Integrator,
    /// Exposure in stops, or `None` for automatic exposure.
    pub exposure: Option<f64>,
    /// Seed of the pixel sample jitter.
    pub seed: u64,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            step: default_render_step(),
            integrator: crate::ray::Integrator::Euler,
            exposure: None,
            seed: 0,
        }
    }
}

/// A validated scene: grid, ambient medium, objects, lights, receiver.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Where it came from: a file path, or `<scene>`.
    pub origin: String,
    text: String,
    /// Grid settings.
    pub grid: GridSettings,
    /// The medium filling everything no object covers.
    pub ambient: Material,
    /// The objects, in file order.
    pub objects: Vec<Object>,
    /// Object indices ordered highest priority first (later first on ties).
    precedence: Vec<usize>,
    /// Light sources.
    pub lights: Vec<Light>,
    /// Optional diffuse receiver plane.
    pub receiver: Option<Receiver>,
    /// The camera, when the file sets one (`[camera]`).
    pub camera: Option<CameraSettings>,
    /// The background (`[background]`; the procedural sky by default).
    pub background: Background,
    /// Eye-ray marching and exposure (`[render]`).
    pub render: RenderSettings,
}

/// A scene file's text (a regular file of at most [`MAX_SCENE_BYTES`],
/// UTF-8).
pub(crate) fn read_text(path: &Path) -> Result<String> {
    let bytes =
        eikon_mesh::load::read_file(path, MAX_SCENE_BYTES).map_err(|source| Error::Read {
            path: path.to_path_buf(),
            source,
        })?;
    String::from_utf8(bytes).map_err(|_| Error::Read {
        path: path.to_path_buf(),
        source: std::io::Error::new(std::io::ErrorKind::InvalidData, "not UTF-8 text"),
    })
}

/// The largest grid coordinate, world units.
pub const MAX_COORDINATE: f64 = 1e9;

/// The most one cell edge may exceed another.
pub const MAX_CELL_ASPECT: f64 = 64.0;

/// The largest scene file read (a scene is text; its data lives in the
/// mesh and volume files it names).
pub const MAX_SCENE_BYTES: u64 = 16 << 20;

/// Changes to a scene's `[grid]` from outside the file (the command line's
/// `--resolution`, `--smoothing` and `--preview`). They are applied before
/// the scene is checked, so every check and the memory estimate see the
/// grid that will be built.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GridOverride {
    /// Voxels along the longest axis; the other axes keep the proportions
    /// of the scene's own resolution.
    pub resolution: Option<u64>,
    /// At most this many voxels along the longest axis (a lower
    /// `resolution` or scene resolution stays).
    pub max_resolution: Option<u64>,
    /// Gaussian sigma in voxels.
    pub smoothing: Option<f64>,
    /// Sharp or smoothed interfaces.
    pub interfaces: Option<crate::region::Interfaces>,
}

impl GridOverride {
    /// The scene's resolution with this override applied.
    fn apply(&self, r: &RawResolution) -> RawResolution {
        let longest = match r {
            RawResolution::Longest(n) => *n,
            RawResolution::PerAxis(d) => d.iter().copied().max().unwrap_or(0),
        };
        let target = match (self.resolution, self.max_resolution) {
            (Some(n), Some(m)) => n.min(m),
            (Some(n), None) => n,
            (None, Some(m)) if longest > m => m,
            _ => return *r,
        };
        match r {
            RawResolution::Longest(_) => RawResolution::Longest(target),
            // Keep the axes' proportions: scale each by target / longest and
            // round, at least one voxel.
            RawResolution::PerAxis(d) => RawResolution::PerAxis(d.map(|x| {
                if longest == 0 {
                    x
                } else {
                    ((x as f64 * target as f64 / longest as f64).round() as u64).max(1)
                }
            })),
        }
    }
}

impl Scene {
    /// Read and check a scene file.
    pub fn load(path: &Path) -> Result<Scene> {
        Scene::load_with(path, &GridOverride::default())
    }

    /// Read a scene file, change its `[grid]` by `grid`, and check it.
    pub fn load_with(path: &Path, grid: &GridOverride) -> Result<Scene> {
        Scene::parse_with(&read_text(path)?, &path.display().to_string(), grid)
    }

    /// Parse and check scene text; `origin` names it in errors.
    pub fn parse(text: &str, origin: &str) -> Result<Scene> {
        Scene::parse_with(text, origin, &GridOverride::default())
    }

    /// [`Scene::parse`] with the `[grid]` changed by `grid` before the checks.
    /// An animated scene (one with `[animation]`) gives its frame 0
    /// ([`crate::animation::Animation`] gives the others).
    pub fn parse_with(text: &str, origin: &str, grid: &GridOverride) -> Result<Scene> {
        if crate::animation::is_animated(text) {
            return crate::animation::Animation::parse_with(text, origin, grid)?.frame(0);
        }
        Scene::parse_static(text, origin, grid)
    }

    /// Parse and check `text` as it stands (an `[animation]` table is
    /// carried, not applied).
    pub(crate) fn parse_static(text: &str, origin: &str, grid: &GridOverride) -> Result<Scene> {
        let c = Checker { origin, text };
        let mut raw: RawScene = deserialize(text, origin)?;
        raw.grid.resolution = grid.apply(&raw.grid.resolution);
        if let Some(sigma) = grid.smoothing {
            raw.grid.smoothing = sigma;
        }
        if let Some(i) = grid.interfaces {
            raw.grid.interfaces = i;
        }
        check::scene(raw, &c)
    }

    /// An error located at a dotted field path of this scene (for problems
    /// found after loading, such as a grid too large for memory).
    pub fn error_at(&self, field: &str, message: impl Into<String>) -> Error {
        let segs = parse_path(field);
        let c = Checker {
            origin: &self.origin,
            text: &self.text,
        };
        c.err(&segs, message)
    }

    /// Index of the object that owns point `p` (highest priority containing
    /// it), or `None` for the ambient medium.
    #[inline]
    pub fn owner(&self, p: DVec3) -> Option<usize> {
        self.precedence
            .iter()
            .copied()
            .find(|&i| self.objects[i].shape.contains(p))
    }

    /// The material at `p` after priority resolution.
    #[inline]
    pub fn material_at(&self, p: DVec3) -> &Material {
        match self.owner(p) {
            Some(i) => &self.objects[i].material,
            None => &self.ambient,
        }
    }

    /// Object indices, highest priority first.
    pub fn precedence(&self) -> &[usize] {
        &self.precedence
    }

    /// Number of index fields: 3 with dispersion, else 1.
    pub fn channels(&self) -> usize {
        if self.grid.dispersion {
            3
        } else {
            1
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GLASS_OF_WATER: &str = r#"
[grid]
resolution = 32
min = [-1, -1, -1]
max = [1, 1, 1]

[[object]]
name = "water"
shape = { type = "cylinder", center = [0, 0, 0], radius = 0.6, height = 1.0 }
index = 1.33
priority = 1

[[object]]
name = "glass"
shape = { type = "revolution", base = [0, -0.6, 0], profile = [[0, 0], [0.65, 0], [0.65, 1.2], [0.55, 1.2], [0.55, 0.1], [0, 0.1]] }
index = 1.5
priority = 2
"#;

    #[test]
    fn priority_resolves_overlap() {
        let s = Scene::parse(GLASS_OF_WATER, "t.toml").unwrap();
        // r = 0.58 lies in the water cylinder and in the glass wall.
        let p = DVec3::new(0.58, 0.0, 0.0);
        assert!(s.objects[0].shape.contains(p) && s.objects[1].shape.contains(p));
        assert_eq!(s.material_at(p).index.value(p, 0), 1.5);
        assert_eq!(
            s.material_at(DVec3::new(0.3, 0.0, 0.0)).index.value(p, 0),
            1.33
        );
        assert_eq!(
            s.material_at(DVec3::new(0.9, 0.0, 0.0)).index.value(p, 0),
            1.0
        );
    }

    fn err(text: &str) -> String {
        Scene::parse(text, "bad.toml").unwrap_err().to_string()
    }

    #[test]
    fn errors_name_line_column_and_field() {
        let e = err("[grid]\nresolution = 8\nmin = [0,0,0]\nmax = [1,1,1]\ncolour = 3\n");
        assert!(e.starts_with("bad.toml:5:1: grid"), "{e}");
        assert!(e.contains("unknown field `colour`"), "{e}");

        let e = err(&GLASS_OF_WATER.replace("index = 1.33", "index = -1.33"));
        assert!(e.contains("object[0].index"), "{e}");
        assert!(e.contains("must be > 0"), "{e}");
        let line = GLASS_OF_WATER
            .lines()
            .position(|l| l.starts_with("index = 1.33"))
            .unwrap()
            + 1;
        assert!(e.starts_with(&format!("bad.toml:{line}:1: ")), "{e}");

        let e = err(&GLASS_OF_WATER.replace("radius = 0.6,", "radius = nan,"));
        assert!(e.contains("object[0].shape.radius"), "{e}");

        let e = err("[grid]\nresolution = 8\nmin = [0,0,0]\nmax = [1,1,1\n");
        assert!(
            e.starts_with("bad.toml:5:1: invalid array: expected `]`"),
            "{e}"
        );
    }

    #[test]
    fn grid_override_sets_the_longest_axis_and_keeps_proportions() {
        let at = |text: &str, g: GridOverride| {
            let s = Scene::parse_with(text, "t.toml", &g).unwrap();
            (s.grid.geometry.dims, s.grid.smoothing)
        };
        // One resolution for the longest axis: the override replaces it.
        let cube = GLASS_OF_WATER;
        let r = |n| GridOverride {
            resolution: Some(n),
            ..GridOverride::default()
        };
        assert_eq!(at(cube, GridOverride::default()), ([32; 3], 0.75));
        assert_eq!(at(cube, r(12)), ([12; 3], 0.75));
        // Per-axis resolutions scale together.
        let slab = cube.replace("resolution = 32", "resolution = [96, 32, 128]");
        assert_eq!(at(&slab, r(64)).0, [48, 16, 64]);
        assert_eq!(at(&slab, r(4)).0, [3, 1, 4]);
        // A cap lowers only what exceeds it.
        let cap = |m| GridOverride {
            max_resolution: Some(m),
            ..GridOverride::default()
        };
        assert_eq!(at(cube, cap(48)).0, [32; 3]);
        assert_eq!(at(cube, cap(16)).0, [16; 3]);
        assert_eq!(at(&slab, cap(32)).0, [24, 8, 32]);
        let both = GridOverride {
            resolution: Some(64),
            max_resolution: Some(20),
            smoothing: Some(0.5),
            interfaces: Some(crate::Interfaces::Sharp),
        };
        assert_eq!(at(cube, both), ([20; 3], 0.5));
        let s = Scene::parse_with(cube, "t.toml", &both).unwrap();
        assert_eq!(s.grid.interfaces, crate::Interfaces::Sharp);
        // Unset, the scene's own setting (the default, sharp) stays.
        let s = Scene::parse_with(cube, "t.toml", &GridOverride::default()).unwrap();
        assert_eq!(s.grid.interfaces, crate::Interfaces::Sharp);
        let smooth = cube.replace("[grid]", "[grid]\ninterfaces = \"smoothed\"");
        let s = Scene::parse_with(&smooth, "t.toml", &GridOverride::default()).unwrap();
        assert_eq!(s.grid.interfaces, crate::Interfaces::Smoothed);
        // A misspelt mode is an error naming the field.
        let e = Scene::parse(
            &cube.replace("[grid]", "[grid]\ninterfaces = \"sharpish\""),
            "t.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("interfaces") && e.contains("sharp"), "{e}");
        // The override passes through the same checks as the file.
        let bad = GridOverride {
            smoothing: Some(9.0),
            ..GridOverride::default()
        };
        let e = Scene::parse_with(cube, "t.toml", &bad)
            .unwrap_err()
            .to_string();
        assert!(e.contains("grid.smoothing"), "{e}");
    }
}
