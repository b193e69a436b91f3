//! Scene files: TOML read through serde, unknown fields rejected, every
//! value checked, and every error located by file, line, column and field.
//!
//! The format is documented field by field in `docs/SCENES.md`.

use crate::error::{Error, Location, Result};
use crate::geometry::GridGeometry;
use crate::mesh::MeshSolid;
use crate::object::{GridExtinction, GridIndex};
use crate::object::{IndexProfile, Material, Object};
use crate::shape::{rotation_from_degrees, Shape};
use crate::vdb::{FloatVolume, VdbError, VdbSolid};
use glam::{DVec2, DVec3};
use serde::de::{self, Deserializer, MapAccess, SeqAccess, Visitor};
use serde::Deserialize;
use std::collections::HashMap;
use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::Arc;

// ---------------------------------------------------------------------------
// Raw file format (serde).

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawScene {
    grid: RawGrid,
    #[serde(default)]
    ambient: RawAmbient,
    #[serde(default, rename = "object")]
    objects: Vec<RawObject>,
    #[serde(default, rename = "light")]
    lights: Vec<RawLight>,
    #[serde(default)]
    receiver: Option<RawReceiver>,
    #[serde(default)]
    camera: Option<RawCamera>,
    #[serde(default)]
    background: Option<RawBackground>,
    #[serde(default)]
    render: Option<RawRender>,
    /// Read by [`crate::animation`]; a frame's scene carries it unchanged.
    #[serde(default, rename = "animation")]
    _animation: Option<toml::Value>,
}

#[derive(Clone, Copy, Deserialize)]
#[serde(
    untagged,
    expecting = "expected a positive whole number of voxels or [nx, ny, nz]"
)]
enum RawResolution {
    Longest(u64),
    PerAxis([u64; 3]),
}

fn default_smoothing() -> f64 {
    0.75
}
fn default_supersample() -> u32 {
    4
}
fn default_one() -> f64 {
    1.0
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawGrid {
    resolution: RawResolution,
    min: [f64; 3],
    max: [f64; 3],
    #[serde(default = "default_smoothing")]
    smoothing: f64,
    #[serde(default = "default_supersample")]
    supersample: u32,
    #[serde(default)]
    dispersion: bool,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawAmbient {
    #[serde(default = "RawIndex::one")]
    index: RawIndex,
    #[serde(default)]
    extinction: [f64; 3],
    #[serde(default)]
    albedo: [f64; 3],
    #[serde(default)]
    g: f64,
    #[serde(default)]
    emission: [f64; 3],
}

impl Default for RawAmbient {
    fn default() -> Self {
        Self {
            index: RawIndex::one(),
            extinction: [0.0; 3],
            albedo: [0.0; 3],
            g: 0.0,
            emission: [0.0; 3],
        }
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawObject {
    #[serde(default)]
    name: Option<String>,
    shape: RawShape,
    index: RawIndex,
    #[serde(default)]
    extinction: RawExtinction,
    #[serde(default)]
    albedo: [f64; 3],
    #[serde(default)]
    g: f64,
    #[serde(default)]
    emission: [f64; 3],
    #[serde(default)]
    priority: i64,
}

#[derive(Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
enum RawShape {
    Sphere {
        center: [f64; 3],
        radius: f64,
    },
    Box {
        center: [f64; 3],
        size: [f64; 3],
        #[serde(default)]
        rotation: [f64; 3],
    },
    RoundedBox {
        center: [f64; 3],
        size: [f64; 3],
        radius: f64,
        #[serde(default)]
        rotation: [f64; 3],
    },
    Cylinder {
        center: [f64; 3],
        radius: f64,
        height: f64,
        #[serde(default)]
        rotation: [f64; 3],
    },
    Revolution {
        base: [f64; 3],
        profile: Vec<[f64; 2]>,
        #[serde(default)]
        rotation: [f64; 3],
    },
    Torus {
        center: [f64; 3],
        major_radius: f64,
        minor_radius: f64,
        #[serde(default)]
        rotation: [f64; 3],
    },
    Superquadric {
        center: [f64; 3],
        radii: [f64; 3],
        exponents: [f64; 2],
        #[serde(default)]
        rotation: [f64; 3],
    },
    HalfSpace {
        point: [f64; 3],
        normal: [f64; 3],
    },
    Vdb {
        file: String,
        grid: String,
        #[serde(default)]
        threshold: Option<f64>,
    },
    Mesh {
        file: String,
        #[serde(default)]
        scale: Option<f64>,
        #[serde(default)]
        translate: [f64; 3],
        #[serde(default)]
        rotation: [f64; 3],
        #[serde(default)]
        smooth: Option<bool>,
    },
    BumpySphere {
        center: [f64; 3],
        radius: f64,
        #[serde(default = "default_bump_amplitude")]
        amplitude: f64,
        #[serde(default = "default_bumps")]
        bumps: usize,
        #[serde(default = "default_one_u64")]
        seed: u64,
        #[serde(default = "default_frequency")]
        frequency: u32,
    },
    Cuboctahedron {
        center: [f64; 3],
        edge: f64,
        #[serde(default)]
        rotation: [f64; 3],
    },
}

fn default_bump_amplitude() -> f64 {
    0.15
}

fn default_bumps() -> usize {
    12
}

fn default_one_u64() -> u64 {
    1
}

/// 20 * 22^2 = 9680 triangles: Walter et al.'s bumpy sphere.
fn default_frequency() -> u32 {
    22
}

/// `index = 1.5`, `index = [1.51, 1.52, 1.53]` or `index = { type = ... }`.
enum RawIndex {
    Scalar(f64),
    Rgb([f64; 3]),
    Profile(RawProfile),
}

impl RawIndex {
    fn one() -> Self {
        RawIndex::Scalar(1.0)
    }
}

#[derive(Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
enum RawProfile {
    Luneburg {
        #[serde(default = "default_one")]
        outer: f64,
    },
    Linear {
        n0: f64,
        gradient: [f64; 3],
        #[serde(default)]
        origin: [f64; 3],
    },
    Vdb {
        #[serde(default)]
        file: Option<String>,
        #[serde(default)]
        grid: Option<String>,
        #[serde(default)]
        scale: Option<f64>,
    },
}

/// An object's `extinction = [r, g, b]`, or `{ type = "vdb", ... }` from a
/// density grid.
enum RawExtinction {
    Rgb([f64; 3]),
    Grid(RawGridMap),
}

impl Default for RawExtinction {
    fn default() -> Self {
        RawExtinction::Rgb([0.0; 3])
    }
}

#[derive(Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
enum RawGridMap {
    Vdb {
        #[serde(default)]
        file: Option<String>,
        #[serde(default)]
        grid: Option<String>,
        scale: [f64; 3],
    },
}

impl<'de> Deserialize<'de> for RawExtinction {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = RawExtinction;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("an [r, g, b] array, or a table with type = \"vdb\"")
            }
            fn visit_seq<A: SeqAccess<'de>>(
                self,
                s: A,
            ) -> std::result::Result<Self::Value, A::Error> {
                Deserialize::deserialize(de::value::SeqAccessDeserializer::new(s))
                    .map(RawExtinction::Rgb)
            }
            fn visit_map<A: MapAccess<'de>>(
                self,
                m: A,
            ) -> std::result::Result<Self::Value, A::Error> {
                Deserialize::deserialize(de::value::MapAccessDeserializer::new(m))
                    .map(RawExtinction::Grid)
            }
        }
        d.deserialize_any(V)
    }
}

/// The constant RGB of a material field (the placeholder of a grid mapping).
trait ConstantRgb {
    fn rgb(&self) -> [f64; 3];
}

impl ConstantRgb for [f64; 3] {
    fn rgb(&self) -> [f64; 3] {
        *self
    }
}

impl ConstantRgb for RawExtinction {
    fn rgb(&self) -> [f64; 3] {
        match self {
            RawExtinction::Rgb(v) => *v,
            RawExtinction::Grid(_) => [0.0; 3],
        }
    }
}

impl<'de> Deserialize<'de> for RawIndex {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = RawIndex;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str(
                    "a number, an [r, g, b] array, or a table with type = \"luneburg\", \"linear\" or \"vdb\"",
                )
            }
            fn visit_f64<E: de::Error>(self, v: f64) -> std::result::Result<RawIndex, E> {
                Ok(RawIndex::Scalar(v))
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> std::result::Result<RawIndex, E> {
                Ok(RawIndex::Scalar(v as f64))
            }
            fn visit_u64<E: de::Error>(self, v: u64) -> std::result::Result<RawIndex, E> {
                Ok(RawIndex::Scalar(v as f64))
            }
            fn visit_seq<A: SeqAccess<'de>>(self, s: A) -> std::result::Result<RawIndex, A::Error> {
                Deserialize::deserialize(de::value::SeqAccessDeserializer::new(s))
                    .map(RawIndex::Rgb)
            }
            fn visit_map<A: MapAccess<'de>>(self, m: A) -> std::result::Result<RawIndex, A::Error> {
                Deserialize::deserialize(de::value::MapAccessDeserializer::new(m))
                    .map(RawIndex::Profile)
            }
        }
        d.deserialize_any(V)
    }
}

#[derive(Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
enum RawLight {
    Directional {
        direction: [f64; 3],
        power: [f64; 3],
    },
    Point {
        position: [f64; 3],
        power: [f64; 3],
    },
    Spot {
        position: [f64; 3],
        direction: [f64; 3],
        angle: f64,
        #[serde(default)]
        falloff: f64,
        power: [f64; 3],
    },
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawReceiver {
    point: [f64; 3],
    normal: [f64; 3],
    albedo: [f64; 3],
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCamera {
    position: [f64; 3],
    target: [f64; 3],
    #[serde(default = "default_up")]
    up: [f64; 3],
    #[serde(default = "default_fov")]
    fov: f64,
    #[serde(default = "default_image")]
    resolution: [u32; 2],
    #[serde(default = "default_samples")]
    samples: u32,
}

fn default_up() -> [f64; 3] {
    [0.0, 1.0, 0.0]
}
fn default_fov() -> f64 {
    40.0
}
fn default_image() -> [u32; 2] {
    [800, 600]
}
fn default_samples() -> u32 {
    1
}

#[derive(Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
enum RawBackground {
    Constant {
        color: [f64; 3],
    },
    Sky {
        #[serde(default = "default_one")]
        intensity: f64,
    },
    Environment {
        file: String,
        #[serde(default = "default_one")]
        intensity: f64,
    },
    Checker {
        point: [f64; 3],
        normal: [f64; 3],
        square: f64,
        colors: [[f64; 3]; 2],
    },
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRender {
    #[serde(default = "default_render_step")]
    step: f64,
    #[serde(default)]
    integrator: RawIntegrator,
    #[serde(default)]
    exposure: Option<f64>,
    #[serde(default)]
    seed: u64,
}

fn default_render_step() -> f64 {
    0.5
}

#[derive(Deserialize, Default, Clone, Copy)]
#[serde(rename_all = "snake_case")]
enum RawIntegrator {
    #[default]
    Euler,
    Rk4,
}

// ---------------------------------------------------------------------------
// Validated scene.

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
    /// Integrator of the eye rays: Euler (eqs 11-12) or RK4.
    pub integrator: crate::ray::Method,
    /// Exposure in stops, or `None` for automatic exposure.
    pub exposure: Option<f64>,
    /// Seed of the pixel sample jitter.
    pub seed: u64,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            step: default_render_step(),
            integrator: crate::ray::Method::Euler,
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

/// `text` read as `T` through serde, a failure located by line, column
/// and field.
pub(crate) fn deserialize<T: serde::de::DeserializeOwned>(text: &str, origin: &str) -> Result<T> {
    let de = toml::Deserializer::new(text);
    serde_path_to_error::deserialize(de).map_err(|e| {
        let field = e.path().to_string();
        let inner = e.into_inner();
        Error::Invalid {
            at: Location {
                file: origin.to_string(),
                line_column: inner.span().map(|s| line_column(text, s.start)),
                field: if field == "." { String::new() } else { field },
            },
            message: inner.message().trim().replace('\n', ": "),
        }
    })
}

/// One step of a field path.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Seg<'a> {
    Key(&'a str),
    Index(usize),
}

fn path_string(path: &[Seg]) -> String {
    let mut s = String::new();
    for seg in path {
        match seg {
            Seg::Key(k) => {
                if !s.is_empty() {
                    s.push('.');
                }
                s.push_str(k);
            }
            Seg::Index(i) => s.push_str(&format!("[{i}]")),
        }
    }
    s
}

fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let offset = offset.min(text.len());
    let before = &text[..offset];
    let line = before.matches('\n').count() + 1;
    let col = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, col)
}

/// Byte offset of the deepest part of `path` that exists in the document.
fn locate(text: &str, path: &[Seg]) -> Option<usize> {
    let doc = toml_edit::ImDocument::parse(text).ok()?;
    let mut item = doc.as_item();
    let mut best = None;
    for seg in path {
        let next = match seg {
            Seg::Key(k) => {
                // Prefer the key's own position: that is where a reader looks.
                let key_span = match item {
                    toml_edit::Item::Table(t) => t.key(k).and_then(|k| k.span()),
                    toml_edit::Item::Value(toml_edit::Value::InlineTable(t)) => {
                        t.key(k).and_then(|k| k.span())
                    }
                    _ => None,
                };
                let next = item.get(*k);
                if let Some(s) = key_span.or_else(|| next.and_then(|n| n.span())) {
                    best = Some(s.start);
                }
                next
            }
            Seg::Index(i) => {
                let next = item.get(*i);
                if let Some(s) = next.and_then(|n| n.span()) {
                    best = Some(s.start);
                }
                next
            }
        };
        match next {
            Some(n) => item = n,
            None => break,
        }
    }
    best
}

/// Builds located errors while a scene is checked.
pub(crate) struct Checker<'a> {
    pub(crate) origin: &'a str,
    pub(crate) text: &'a str,
}

impl Checker<'_> {
    pub(crate) fn err(&self, path: &[Seg], message: impl Into<String>) -> Error {
        Error::Invalid {
            at: Location {
                file: self.origin.to_string(),
                line_column: locate(self.text, path).map(|o| line_column(self.text, o)),
                field: path_string(path),
            },
            message: message.into(),
        }
    }

    fn finite(&self, path: &[Seg], v: &[f64]) -> Result<()> {
        if v.iter().all(|x| x.is_finite()) {
            Ok(())
        } else {
            Err(self.err(path, "must be a finite number (not NaN or infinity)"))
        }
    }

    fn vec3(&self, path: &[Seg], v: [f64; 3]) -> Result<DVec3> {
        self.finite(path, &v)?;
        Ok(DVec3::from_array(v))
    }

    fn positive(&self, path: &[Seg], v: f64) -> Result<f64> {
        self.finite(path, &[v])?;
        if v > 0.0 {
            Ok(v)
        } else {
            Err(self.err(path, format!("must be > 0, got {v}")))
        }
    }

    fn unit(&self, path: &[Seg], v: [f64; 3]) -> Result<DVec3> {
        let d = self.vec3(path, v)?;
        if d.length() > 0.0 {
            Ok(d.normalize())
        } else {
            Err(self.err(path, "must be a non-zero vector"))
        }
    }

    fn rgb_in(&self, path: &[Seg], v: [f64; 3], lo: f64, hi: f64) -> Result<DVec3> {
        let d = self.vec3(path, v)?;
        if v.iter().all(|x| (lo..=hi).contains(x)) {
            Ok(d)
        } else {
            Err(self.err(
                path,
                format!("each component must lie in [{lo}, {hi}], got {v:?}"),
            ))
        }
    }

    fn index_value(&self, path: &[Seg], n: f64) -> Result<f64> {
        self.finite(path, &[n])?;
        if n > 0.0 {
            Ok(n)
        } else {
            Err(self.err(path, format!("refractive index must be > 0, got {n}")))
        }
    }
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
        Scene::check(raw, &c)
    }

    fn check(raw: RawScene, c: &Checker) -> Result<Scene> {
        use Seg::{Index as I, Key as K};
        let grid = check_grid(c, &raw.grid)?;
        let a = &raw.ambient;
        if let RawIndex::Profile(_) = a.index {
            return Err(c.err(
                &[K("ambient"), K("index")],
                "the ambient index must be a number (or [r, g, b] with dispersion)",
            ));
        }
        let ambient = check_material(c, &grid, &[K("ambient")], a.fields(), None)?;
        let mut objects = Vec::with_capacity(raw.objects.len());
        let mut volumes = Volumes::default();
        for (i, o) in raw.objects.iter().enumerate() {
            let shape = check_shape(c, &[K("object"), I(i), K("shape")], &o.shape, &mut volumes)?;
            let mut material =
                check_material(c, &grid, &[K("object"), I(i)], o.fields(), Some(&shape))?;
            attach_grids(c, &mut volumes, i, o, &mut material)?;
            objects.push(Object {
                name: o.name.clone().unwrap_or_else(|| format!("object{i}")),
                shape,
                material,
                priority: o.priority,
            });
        }
        let lights = (raw.lights.iter().enumerate())
            .map(|(i, l)| check_light(c, i, l))
            .collect::<Result<Vec<_>>>()?;
        let receiver = match &raw.receiver {
            None => None,
            Some(r) => Some(Receiver {
                point: c.vec3(&[K("receiver"), K("point")], r.point)?,
                normal: c.unit(&[K("receiver"), K("normal")], r.normal)?,
                albedo: c.rgb_in(&[K("receiver"), K("albedo")], r.albedo, 0.0, 1.0)?,
            }),
        };

        let camera = raw
            .camera
            .as_ref()
            .map(|r| check_camera(c, r))
            .transpose()?;
        let background = match &raw.background {
            None => Background::Sky { intensity: 1.0 },
            Some(b) => check_background(c, b)?,
        };
        let render = match &raw.render {
            None => RenderSettings::default(),
            Some(r) => check_render(c, r)?,
        };

        // Highest priority first; among equals the later object first.
        let mut precedence: Vec<usize> = (0..objects.len()).rev().collect();
        precedence.sort_by_key(|&i| std::cmp::Reverse(objects[i].priority));

        Ok(Scene {
            origin: c.origin.to_string(),
            text: c.text.to_string(),
            grid,
            ambient,
            objects,
            precedence,
            lights,
            receiver,
            camera,
            background,
            render,
        })
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

fn parse_path(field: &str) -> Vec<Seg<'_>> {
    let mut out = Vec::new();
    for part in field.split('.') {
        let (key, rest) = part.split_once('[').unwrap_or((part, ""));
        if !key.is_empty() {
            out.push(Seg::Key(key));
        }
        for idx in rest.split('[') {
            if let Ok(i) = idx.trim_end_matches(']').parse() {
                out.push(Seg::Index(i));
            }
        }
    }
    out
}

/// The optical fields an object and the ambient medium share.
struct MaterialFields<'a> {
    index: &'a RawIndex,
    extinction: [f64; 3],
    albedo: [f64; 3],
    g: f64,
    emission: [f64; 3],
}

/// `fields()` for the two raw types that carry a material.
macro_rules! material_fields {
    ($($raw:ty),*) => {$(
        impl $raw {
            fn fields(&self) -> MaterialFields<'_> {
                MaterialFields {
                    index: &self.index,
                    extinction: ConstantRgb::rgb(&self.extinction),
                    albedo: self.albedo,
                    g: self.g,
                    emission: self.emission,
                }
            }
        }
    )*};
}
material_fields!(RawAmbient, RawObject);

fn check_grid(c: &Checker, g: &RawGrid) -> Result<GridSettings> {
    use Seg::Key as K;
    let min = c.vec3(&[K("grid"), K("min")], g.min)?;
    let max = c.vec3(&[K("grid"), K("max")], g.max)?;
    if !(max.cmpgt(min).all()) {
        return Err(c.err(
            &[K("grid"), K("max")],
            format!("must exceed grid.min on every axis ({max} vs {min})"),
        ));
    }
    for (key, v) in [("min", min), ("max", max)] {
        if v.abs().max_element() > MAX_COORDINATE {
            return Err(c.err(
                &[K("grid"), K(key)],
                format!(
                    "coordinates beyond +-{MAX_COORDINATE:e} world units ({v}): use a smaller unit"
                ),
            ));
        }
    }
    let extent = max - min;
    let res = &[K("grid"), K("resolution")];
    let dims = match g.resolution {
        RawResolution::Longest(n) => {
            if n == 0 {
                return Err(c.err(res, "must be at least 1"));
            }
            let h = extent.max_element() / n as f64;
            let d = (extent / h).round().max(DVec3::ONE);
            [d.x as u64, d.y as u64, d.z as u64]
        }
        RawResolution::PerAxis(d) => {
            if d.contains(&0) {
                return Err(c.err(res, "every axis needs at least 1 voxel"));
            }
            d
        }
    };
    let dims = dims.map(|d| usize::try_from(d).unwrap_or(usize::MAX));
    if dims
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .is_none()
    {
        return Err(c.err(res, format!("{dims:?} voxels cannot even be counted")));
    }
    // Cells far from cubic make the voxel size (the smallest edge) that
    // steps and patches are measured in meaningless along the long edges,
    // and the work of crossing the grid unbounded.
    let spacing = extent / DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64);
    let aspect = spacing.max_element() / spacing.min_element();
    if aspect.is_nan() || aspect > MAX_CELL_ASPECT {
        return Err(c.err(
            res,
            format!(
                "cells of {:?} voxels over {extent} are {aspect:.3e} times longer on one axis than on another (at most {MAX_CELL_ASPECT}): give each axis voxels in proportion to its extent",
                dims
            ),
        ));
    }
    let smoothing = g.smoothing;
    c.finite(&[K("grid"), K("smoothing")], &[smoothing])?;
    if !(0.0..=8.0).contains(&smoothing) {
        return Err(c.err(
            &[K("grid"), K("smoothing")],
            format!("sigma in voxels must lie in [0, 8], got {smoothing}"),
        ));
    }
    if !(1..=16).contains(&g.supersample) {
        return Err(c.err(
            &[K("grid"), K("supersample")],
            format!(
                "must lie in 1..=16 sub-samples per axis, got {}",
                g.supersample
            ),
        ));
    }
    Ok(GridSettings {
        geometry: GridGeometry::new(dims, min, max),
        smoothing,
        supersample: g.supersample as usize,
        dispersion: g.dispersion,
    })
}

/// The index profile at field path `ip`; `shape` is the object's (None for
/// the ambient medium).
fn check_index(
    c: &Checker,
    grid: &GridSettings,
    ip: &[Seg],
    index: &RawIndex,
    shape: Option<&Shape>,
) -> Result<IndexProfile> {
    let sub = |k| [ip, &[Seg::Key(k)]].concat();
    Ok(match index {
        RawIndex::Scalar(n) => IndexProfile::Constant([c.index_value(ip, *n)?; 3]),
        RawIndex::Rgb(n) => {
            if !grid.dispersion {
                return Err(c.err(ip, "an [r, g, b] index needs grid.dispersion = true"));
            }
            for &v in n {
                c.index_value(ip, v)?;
            }
            IndexProfile::Constant(*n)
        }
        RawIndex::Profile(RawProfile::Luneburg { outer }) => {
            let outer = c.index_value(&sub("outer"), *outer)?;
            match shape {
                Some(Shape::Sphere { center, radius }) => IndexProfile::Luneburg {
                    center: *center,
                    radius: *radius,
                    outer,
                },
                _ => {
                    return Err(c.err(
                        ip,
                        "a Luneburg profile needs a sphere shape (it takes the sphere's centre and radius)",
                    ))
                }
            }
        }
        RawIndex::Profile(RawProfile::Linear {
            n0,
            gradient,
            origin,
        }) => {
            let prof = IndexProfile::Linear {
                n0: c.index_value(&sub("n0"), *n0)?,
                gradient: c.vec3(&sub("gradient"), *gradient)?,
                origin: c.vec3(&sub("origin"), *origin)?,
            };
            // n must stay positive wherever the object meets the grid (with
            // room for the smoothing halo): check the corners of that box,
            // where a linear function takes its extremes.
            let geom = &grid.geometry;
            let halo = geom.spacing() * (4.0 * grid.smoothing + 2.0);
            let (mut lo, mut hi) = (geom.min - halo, geom.max + halo);
            if let Some((a, b)) = shape.and_then(Shape::aabb) {
                lo = lo.max(a);
                hi = hi.min(b);
            }
            for corner in 0..8 {
                let q = DVec3::new(
                    if corner & 1 == 0 { lo.x } else { hi.x },
                    if corner & 2 == 0 { lo.y } else { hi.y },
                    if corner & 4 == 0 { lo.z } else { hi.z },
                );
                let n = prof.value(q, 0);
                if (n.is_nan() || n <= 0.0) && lo.cmple(hi).all() {
                    return Err(c.err(
                        ip,
                        format!("the linear index reaches {n:.4} <= 0 at {q} inside the grid"),
                    ));
                }
            }
            prof
        }
        // Filled in from the grid by `attach_grids`.
        RawIndex::Profile(RawProfile::Vdb { .. }) => IndexProfile::Constant([1.0; 3]),
    })
}

/// The material whose fields sit under path `base`.
fn check_material(
    c: &Checker,
    grid: &GridSettings,
    base: &[Seg],
    m: MaterialFields,
    shape: Option<&Shape>,
) -> Result<Material> {
    let p = |k| [base, &[Seg::Key(k)]].concat();
    let index = check_index(c, grid, &p("index"), m.index, shape)?;
    let extinction = c.vec3(&p("extinction"), m.extinction)?;
    if extinction.min_element() < 0.0 {
        return Err(c.err(&p("extinction"), "extinction must be >= 0 (1 / world unit)"));
    }
    if extinction.max_element() > MAX_EXTINCTION {
        return Err(c.err(
            &p("extinction"),
            format!(
                "extinction {:e} exceeds the limit of {MAX_EXTINCTION:e} per world unit (stored as 32-bit floats)",
                extinction.max_element()
            ),
        ));
    }
    let albedo = c.rgb_in(&p("albedo"), m.albedo, 0.0, 1.0)?;
    c.finite(&p("g"), &[m.g])?;
    if !(m.g > -1.0 && m.g < 1.0) {
        return Err(c.err(
            &p("g"),
            format!("Henyey-Greenstein g must lie in (-1, 1), got {}", m.g),
        ));
    }
    let emission = c.vec3(&p("emission"), m.emission)?;
    if emission.min_element() < 0.0 {
        return Err(c.err(&p("emission"), "emission must be >= 0"));
    }
    Ok(Material {
        index,
        extinction,
        albedo,
        g: m.g,
        emission,
        index_grid: None,
        extinction_grid: None,
    })
}

/// Light `i` of the file.
fn check_camera(c: &Checker, r: &RawCamera) -> Result<CameraSettings> {
    let p = |k| [Seg::Key("camera"), Seg::Key(k)];
    let position = c.vec3(&p("position"), r.position)?;
    let target = c.vec3(&p("target"), r.target)?;
    if (target - position).length() == 0.0 {
        return Err(c.err(
            &p("target"),
            "the camera must look somewhere: target equals position",
        ));
    }
    let up = c.unit(&p("up"), r.up)?;
    if up.cross((target - position).normalize()).length() < 1e-6 {
        return Err(c.err(&p("up"), "up must not be parallel to the view direction"));
    }
    c.finite(&p("fov"), &[r.fov])?;
    if !(r.fov > 0.0 && r.fov < 180.0) {
        return Err(c.err(
            &p("fov"),
            format!("field of view must lie in (0, 180) degrees, got {}", r.fov),
        ));
    }
    let [w, h] = r.resolution;
    if w == 0 || h == 0 || w > 16384 || h > 16384 {
        return Err(c.err(
            &p("resolution"),
            format!("image size must be 1 to 16384 pixels a side, got {w} x {h}"),
        ));
    }
    if r.samples == 0 || r.samples > 4096 {
        return Err(c.err(
            &p("samples"),
            format!("samples per pixel must lie in 1..=4096, got {}", r.samples),
        ));
    }
    Ok(CameraSettings {
        position,
        target,
        up,
        fov: r.fov,
        resolution: r.resolution,
        samples: r.samples,
    })
}

fn check_background(c: &Checker, b: &RawBackground) -> Result<Background> {
    let p = |k| [Seg::Key("background"), Seg::Key(k)];
    let scale = |v: f64| -> Result<f64> {
        c.finite(&p("intensity"), &[v])?;
        if v < 0.0 {
            return Err(c.err(&p("intensity"), "intensity must be >= 0"));
        }
        Ok(v)
    };
    let radiance = |path: &[Seg], v: [f64; 3]| -> Result<DVec3> {
        let v = c.vec3(path, v)?;
        if v.min_element() < 0.0 {
            return Err(c.err(path, "radiance must be >= 0"));
        }
        Ok(v)
    };
    Ok(match b {
        RawBackground::Constant { color } => Background::Constant(radiance(&p("color"), *color)?),
        RawBackground::Sky { intensity } => Background::Sky {
            intensity: scale(*intensity)?,
        },
        RawBackground::Environment { file, intensity } => {
            let base = Path::new(c.origin).parent().unwrap_or(Path::new(""));
            Background::Environment {
                file: base.join(file),
                intensity: scale(*intensity)?,
            }
        }
        RawBackground::Checker {
            point,
            normal,
            square,
            colors,
        } => {
            let path = |i| [Seg::Key("background"), Seg::Key("colors"), Seg::Index(i)];
            Background::Checker {
                point: c.vec3(&p("point"), *point)?,
                normal: c.unit(&p("normal"), *normal)?,
                square: c.positive(&p("square"), *square)?,
                colors: [
                    radiance(&path(0), colors[0])?,
                    radiance(&path(1), colors[1])?,
                ],
            }
        }
    })
}

fn check_render(c: &Checker, r: &RawRender) -> Result<RenderSettings> {
    let p = |k| [Seg::Key("render"), Seg::Key(k)];
    let step = c.positive(&p("step"), r.step)?;
    if step > 4.0 {
        return Err(c.err(
            &p("step"),
            format!("step must be at most 4 voxels, got {step}"),
        ));
    }
    if let Some(e) = r.exposure {
        c.finite(&p("exposure"), &[e])?;
    }
    Ok(RenderSettings {
        step,
        integrator: match r.integrator {
            RawIntegrator::Euler => crate::ray::Method::Euler,
            RawIntegrator::Rk4 => crate::ray::Method::Rk4,
        },
        exposure: r.exposure,
        seed: r.seed,
    })
}

fn check_light(c: &Checker, i: usize, l: &RawLight) -> Result<Light> {
    let p = |k| [Seg::Key("light"), Seg::Index(i), Seg::Key(k)];
    let power = |v| -> Result<DVec3> {
        let v = c.vec3(&p("power"), v)?;
        if v.min_element() < 0.0 {
            return Err(c.err(&p("power"), "power must be >= 0"));
        }
        if v.max_element() > MAX_LIGHT_POWER {
            return Err(c.err(
                &p("power"),
                format!(
                    "power {:e} exceeds the limit of {MAX_LIGHT_POWER:e} per channel (the light volumes are 32-bit floats)",
                    v.max_element()
                ),
            ));
        }
        Ok(v)
    };
    Ok(match l {
        RawLight::Directional {
            direction,
            power: pw,
        } => Light::Directional {
            direction: c.unit(&p("direction"), *direction)?,
            power: power(*pw)?,
        },
        RawLight::Point {
            position,
            power: pw,
        } => Light::Point {
            position: c.vec3(&p("position"), *position)?,
            power: power(*pw)?,
        },
        RawLight::Spot {
            position,
            direction,
            angle,
            falloff,
            power: pw,
        } => {
            c.finite(&p("angle"), &[*angle])?;
            if !(*angle > 0.0 && *angle <= 90.0) {
                return Err(c.err(&p("angle"), "cone half-angle must lie in (0, 90] degrees"));
            }
            c.finite(&p("falloff"), &[*falloff])?;
            if !(0.0..=*angle).contains(falloff) {
                return Err(c.err(&p("falloff"), "falloff must lie in [0, angle] degrees"));
            }
            Light::Spot {
                position: c.vec3(&p("position"), *position)?,
                direction: c.unit(&p("direction"), *direction)?,
                angle: *angle,
                falloff: *falloff,
                power: power(*pw)?,
            }
        }
    })
}

fn check_shape(c: &Checker, sp: &[Seg], s: &RawShape, volumes: &mut Volumes) -> Result<Shape> {
    let f = |k: &'static str| [sp, &[Seg::Key(k)]].concat();
    let rot = |r: [f64; 3]| -> Result<glam::DMat3> {
        c.finite(&f("rotation"), &r)?;
        Ok(rotation_from_degrees(r))
    };
    let size = |v: [f64; 3]| -> Result<DVec3> {
        let v = c.vec3(&f("size"), v)?;
        if v.min_element() > 0.0 {
            Ok(v)
        } else {
            Err(c.err(&f("size"), "every edge length must be > 0"))
        }
    };
    Ok(match s {
        RawShape::Sphere { center, radius } => Shape::Sphere {
            center: c.vec3(&f("center"), *center)?,
            radius: c.positive(&f("radius"), *radius)?,
        },
        RawShape::Box {
            center,
            size: sz,
            rotation,
        } => Shape::Box {
            center: c.vec3(&f("center"), *center)?,
            half: size(*sz)? * 0.5,
            radius: 0.0,
            rot: rot(*rotation)?,
        },
        RawShape::RoundedBox {
            center,
            size: sz,
            radius,
            rotation,
        } => {
            let half = size(*sz)? * 0.5;
            let r = c.positive(&f("radius"), *radius)?;
            if r > half.min_element() {
                return Err(c.err(
                    &f("radius"),
                    "rounding radius exceeds half the smallest edge",
                ));
            }
            Shape::Box {
                center: c.vec3(&f("center"), *center)?,
                half,
                radius: r,
                rot: rot(*rotation)?,
            }
        }
        RawShape::Cylinder {
            center,
            radius,
            height,
            rotation,
        } => Shape::Cylinder {
            center: c.vec3(&f("center"), *center)?,
            radius: c.positive(&f("radius"), *radius)?,
            half_height: 0.5 * c.positive(&f("height"), *height)?,
            rot: rot(*rotation)?,
        },
        RawShape::Revolution {
            base,
            profile,
            rotation,
        } => {
            if profile.len() < 3 {
                return Err(c.err(
                    &f("profile"),
                    "a profile needs at least 3 [radius, height] points",
                ));
            }
            let mut pts = Vec::with_capacity(profile.len());
            let mut area2 = 0.0;
            for (i, q) in profile.iter().enumerate() {
                let at = [sp, &[Seg::Key("profile"), Seg::Index(i)]].concat();
                c.finite(&at, q)?;
                if q[0] < 0.0 {
                    return Err(c.err(&at, "profile radius must be >= 0"));
                }
                pts.push(DVec2::new(q[0], q[1]));
            }
            for i in 0..pts.len() {
                area2 += pts[i].perp_dot(pts[(i + 1) % pts.len()]);
            }
            if area2.abs() < 1e-12 {
                return Err(c.err(&f("profile"), "the profile polygon encloses no area"));
            }
            Shape::Revolution {
                base: c.vec3(&f("base"), *base)?,
                profile: pts,
                rot: rot(*rotation)?,
            }
        }
        RawShape::Torus {
            center,
            major_radius,
            minor_radius,
            rotation,
        } => Shape::Torus {
            center: c.vec3(&f("center"), *center)?,
            major: c.positive(&f("major_radius"), *major_radius)?,
            minor: c.positive(&f("minor_radius"), *minor_radius)?,
            rot: rot(*rotation)?,
        },
        RawShape::Superquadric {
            center,
            radii,
            exponents,
            rotation,
        } => {
            let r = c.vec3(&f("radii"), *radii)?;
            if r.min_element() <= 0.0 {
                return Err(c.err(&f("radii"), "every radius must be > 0"));
            }
            c.finite(&f("exponents"), exponents)?;
            if !exponents.iter().all(|e| (0.05..=4.0).contains(e)) {
                return Err(c.err(&f("exponents"), "exponents must lie in [0.05, 4]"));
            }
            Shape::Superquadric {
                center: c.vec3(&f("center"), *center)?,
                radii: r,
                e1: exponents[0],
                e2: exponents[1],
                rot: rot(*rotation)?,
            }
        }
        RawShape::HalfSpace { point, normal } => Shape::HalfSpace {
            point: c.vec3(&f("point"), *point)?,
            normal: c.unit(&f("normal"), *normal)?,
        },
        RawShape::Vdb {
            file,
            grid,
            threshold,
        } => {
            let volume = volumes.load(c, sp, file, grid)?;
            let t = match threshold {
                Some(t) => {
                    c.finite(&f("threshold"), &[*t])?;
                    *t
                }
                None => volume.background as f64,
            };
            let solid = VdbSolid::new(volume.clone(), t);
            if solid.inside_voxels() == 0 && volume.background as f64 <= t {
                let (lo, hi) = volume.range();
                return Err(c.err(
                    &f("threshold"),
                    format!(
                        "no voxel of grid `{grid}` exceeds {t} (its values span {lo} to {hi}): the solid would be empty"
                    ),
                ));
            }
            Shape::Vdb(Arc::new(solid))
        }
        RawShape::Mesh {
            file,
            scale,
            translate,
            rotation,
            smooth,
        } => {
            let base = Path::new(c.origin).parent().unwrap_or(Path::new(""));
            let path = base.join(file);
            let mut mesh = eikon_mesh::load(&path).map_err(|e| c.err(&f("file"), e.to_string()))?;
            let scale = match scale {
                Some(k) => c.positive(&f("scale"), *k)?,
                None => 1.0,
            };
            let map = glam::DAffine3::from_translation(c.vec3(&f("translate"), *translate)?)
                * glam::DAffine3::from_mat3(rot(*rotation)?)
                * glam::DAffine3::from_scale(DVec3::splat(scale));
            mesh.transform(map)
                .map_err(|e| c.err(&f("file"), e.to_string()))?;
            mesh_shape(c, &f("file"), mesh, smooth.unwrap_or(true))?
        }
        RawShape::BumpySphere {
            center,
            radius,
            amplitude,
            bumps,
            seed,
            frequency,
        } => {
            let center = c.vec3(&f("center"), *center)?;
            let radius = c.positive(&f("radius"), *radius)?;
            if !(1..=200).contains(frequency) {
                return Err(c.err(
                    &f("frequency"),
                    format!("must lie in 1..=200 (20 f^2 triangles), got {frequency}"),
                ));
            }
            let mut mesh = eikon_mesh::BumpySphere::new(radius, *amplitude, *bumps, *seed)
                .and_then(|b| b.mesh(*frequency))
                .map_err(|e| c.err(sp, e.to_string()))?;
            mesh.transform(glam::DAffine3::from_translation(center))
                .map_err(|e| c.err(sp, e.to_string()))?;
            mesh_shape(c, sp, mesh, true)?
        }
        RawShape::Cuboctahedron {
            center,
            edge,
            rotation,
        } => {
            let edge = c.positive(&f("edge"), *edge)?;
            let mut mesh =
                eikon_mesh::cuboctahedron(edge).map_err(|e| c.err(&f("edge"), e.to_string()))?;
            let map = glam::DAffine3::from_translation(c.vec3(&f("center"), *center)?)
                * glam::DAffine3::from_mat3(rot(*rotation)?);
            mesh.transform(map).map_err(|e| c.err(sp, e.to_string()))?;
            mesh_shape(c, sp, mesh, false)?
        }
    })
}

/// A mesh shape, once its mesh is known to bound a solid: closed, manifold,
/// consistently oriented, outward (a mesh wound inside out is flipped). A
/// file that repeats vertices along seams (exporters do, for per-corner
/// normals or texture coordinates) is welded at bit-identical positions
/// first; its normals are kept.
fn mesh_shape(c: &Checker, at: &[Seg], mut mesh: eikon_mesh::Mesh, smooth: bool) -> Result<Shape> {
    if mesh.require_closed().is_err() {
        let mut welded = mesh.clone();
        if welded.weld(0.0).is_ok() && welded.require_closed().is_ok() {
            mesh = welded;
        }
    }
    let report = mesh
        .require_closed()
        .map_err(|e| c.err(at, e.to_string()))?;
    if report.signed_volume < 0.0 {
        mesh.flip();
    }
    Ok(Shape::Mesh(Arc::new(MeshSolid::new(
        Arc::new(mesh),
        smooth,
    ))))
}

/// VDB float grids read while checking a scene, shared by the fields that
/// name the same file and grid.
#[derive(Default)]
struct Volumes(HashMap<(PathBuf, String), Arc<FloatVolume>>);

impl Volumes {
    /// Grid `grid` of `file` (relative to the scene file); errors are
    /// located at `at.file` or `at.grid`.
    fn load(
        &mut self,
        c: &Checker,
        at: &[Seg],
        file: &str,
        grid: &str,
    ) -> Result<Arc<FloatVolume>> {
        let base = Path::new(c.origin).parent().unwrap_or(Path::new(""));
        let path = base.join(file);
        let key = (path.clone(), grid.to_string());
        if let Some(v) = self.0.get(&key) {
            return Ok(v.clone());
        }
        let v = crate::vdb::read_float_grid(&path, grid).map_err(|e| {
            let field = match e {
                VdbError::NoSuchGrid { .. } | VdbError::WrongType { .. } => "grid",
                _ => "file",
            };
            c.err(&[at, &[Seg::Key(field)]].concat(), e.to_string())
        })?;
        if !v.is_finite() {
            return Err(c.err(
                &[at, &[Seg::Key("grid")]].concat(),
                format!(
                    "{}: grid `{grid}` holds NaN or infinite values",
                    path.display()
                ),
            ));
        }
        let v = Arc::new(v);
        self.0.insert(key, v.clone());
        Ok(v)
    }
}

/// Index and extinction of object `i` from VDB grids, where the file asks
/// for them (`index = { type = "vdb", ... }`, `extinction = { type = "vdb",
/// ... }`). `file` and `grid` default to those of a VDB shape.
fn attach_grids(
    c: &Checker,
    volumes: &mut Volumes,
    i: usize,
    o: &RawObject,
    m: &mut Material,
) -> Result<()> {
    use Seg::{Index as I, Key as K};
    let from_shape = match &o.shape {
        RawShape::Vdb { file, grid, .. } => Some((file, grid)),
        _ => None,
    };
    let source =
        |at: &[Seg], file: &Option<String>, grid: &Option<String>| -> Result<(String, String)> {
            let pick = |own: &Option<String>, shape: Option<&String>, key: &'static str| {
                own.clone().or_else(|| shape.cloned()).ok_or_else(|| {
                    c.err(
                        at,
                        format!("`{key}` is required (or a shape of type \"vdb\" to take it from)"),
                    )
                })
            };
            Ok((
                pick(file, from_shape.map(|s| s.0), "file")?,
                pick(grid, from_shape.map(|s| s.1), "grid")?,
            ))
        };
    if let RawIndex::Profile(RawProfile::Vdb { file, grid, scale }) = &o.index {
        let at = [K("object"), I(i), K("index")];
        let (file, grid) = source(&at, file, grid)?;
        let volume = volumes.load(c, &at, &file, &grid)?;
        if let Some(k) = scale {
            c.finite(&[&at[..], &[K("scale")]].concat(), &[*k])?;
        }
        let map = |v: f32| match scale {
            None => v as f64,
            Some(k) => 1.0 + k * v as f64,
        };
        let (lo, hi) = volume.range();
        let (n_lo, n_hi) = (map(lo).min(map(hi)), map(lo).max(map(hi)));
        if n_lo <= 0.0 {
            return Err(c.err(
                &at,
                format!(
                    "the index from grid `{grid}` reaches {n_lo} <= 0 (grid values {lo} to {hi}); the refractive index must be > 0"
                ),
            ));
        }
        m.index = IndexProfile::Constant([n_hi; 3]);
        m.index_grid = Some(GridIndex {
            volume,
            scale: *scale,
        });
    }
    if let RawExtinction::Grid(RawGridMap::Vdb { file, grid, scale }) = &o.extinction {
        let at = [K("object"), I(i), K("extinction")];
        let (file, grid) = source(&at, file, grid)?;
        let volume = volumes.load(c, &at, &file, &grid)?;
        let sp = [&at[..], &[K("scale")]].concat();
        let scale = c.vec3(&sp, *scale)?;
        if scale.min_element() < 0.0 {
            return Err(c.err(&sp, "extinction scale must be >= 0"));
        }
        let (lo, hi) = volume.range();
        if lo < 0.0 && scale.max_element() > 0.0 {
            return Err(c.err(
                &at,
                format!(
                    "grid `{grid}` holds negative values (down to {lo}): extinction would be < 0"
                ),
            ));
        }
        m.extinction = scale * hi as f64;
        if m.extinction.max_element() > MAX_EXTINCTION {
            return Err(c.err(
                &sp,
                format!(
                    "the extinction reaches {:e} (grid maximum {hi} times the scale), over the limit of {MAX_EXTINCTION:e} per world unit",
                    m.extinction.max_element()
                ),
            ));
        }
        m.extinction_grid = Some(GridExtinction { volume, scale });
    }
    Ok(())
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
        };
        assert_eq!(at(cube, both), ([20; 3], 0.5));
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
