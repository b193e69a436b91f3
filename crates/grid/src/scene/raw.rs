//! The scene file's schema as serde reads it: every table and field of
//! `docs/SCENES.md`, unknown fields rejected. Values are checked, and
//! turned into the public types, by [`super::check`].

use crate::region::Interfaces;
use serde::de::{self, Deserializer, MapAccess, SeqAccess, Visitor};
use serde::Deserialize;
use std::fmt;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawScene {
    pub(super) grid: RawGrid,
    #[serde(default)]
    pub(super) ambient: RawAmbient,
    #[serde(default, rename = "object")]
    pub(super) objects: Vec<RawObject>,
    #[serde(default, rename = "light")]
    pub(super) lights: Vec<RawLight>,
    #[serde(default)]
    pub(super) receiver: Option<RawReceiver>,
    #[serde(default)]
    pub(super) camera: Option<RawCamera>,
    #[serde(default)]
    pub(super) background: Option<RawBackground>,
    #[serde(default)]
    pub(super) render: Option<RawRender>,
    /// Read by [`crate::animation`]; a frame's scene carries it unchanged.
    #[serde(default, rename = "animation")]
    pub(super) _animation: Option<toml::Value>,
}

#[derive(Clone, Copy, Deserialize)]
#[serde(
    untagged,
    expecting = "expected a positive whole number of voxels or [nx, ny, nz]"
)]
pub(super) enum RawResolution {
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
pub(super) struct RawGrid {
    pub(super) resolution: RawResolution,
    pub(super) min: [f64; 3],
    pub(super) max: [f64; 3],
    #[serde(default = "default_smoothing")]
    pub(super) smoothing: f64,
    #[serde(default = "default_supersample")]
    pub(super) supersample: u32,
    #[serde(default)]
    pub(super) dispersion: bool,
    #[serde(default)]
    pub(super) interfaces: Interfaces,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawAmbient {
    #[serde(default = "RawIndex::one")]
    pub(super) index: RawIndex,
    #[serde(default)]
    pub(super) extinction: [f64; 3],
    #[serde(default)]
    pub(super) albedo: [f64; 3],
    #[serde(default)]
    pub(super) g: f64,
    #[serde(default)]
    pub(super) emission: [f64; 3],
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
pub(super) struct RawObject {
    #[serde(default)]
    pub(super) name: Option<String>,
    pub(super) shape: RawShape,
    pub(super) index: RawIndex,
    #[serde(default)]
    pub(super) extinction: RawExtinction,
    #[serde(default)]
    pub(super) albedo: [f64; 3],
    #[serde(default)]
    pub(super) g: f64,
    #[serde(default)]
    pub(super) emission: [f64; 3],
    #[serde(default)]
    pub(super) priority: i64,
}

#[derive(Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub(super) enum RawShape {
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
pub(super) enum RawIndex {
    Scalar(f64),
    Rgb([f64; 3]),
    Profile(RawProfile),
}

impl RawIndex {
    pub(super) fn one() -> Self {
        RawIndex::Scalar(1.0)
    }
}

#[derive(Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub(super) enum RawProfile {
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
pub(super) enum RawExtinction {
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
pub(super) enum RawGridMap {
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
pub(super) trait ConstantRgb {
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
pub(super) enum RawLight {
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
pub(super) struct RawReceiver {
    pub(super) point: [f64; 3],
    pub(super) normal: [f64; 3],
    pub(super) albedo: [f64; 3],
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawCamera {
    pub(super) position: [f64; 3],
    pub(super) target: [f64; 3],
    #[serde(default = "default_up")]
    pub(super) up: [f64; 3],
    #[serde(default = "default_fov")]
    pub(super) fov: f64,
    #[serde(default = "default_image")]
    pub(super) resolution: [u32; 2],
    #[serde(default = "default_samples")]
    pub(super) samples: u32,
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
pub(super) enum RawBackground {
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
pub(super) struct RawRender {
    #[serde(default = "default_render_step")]
    pub(super) step: f64,
    #[serde(default)]
    pub(super) integrator: RawIntegrator,
    #[serde(default)]
    pub(super) exposure: Option<f64>,
    #[serde(default)]
    pub(super) seed: u64,
}

pub(super) fn default_render_step() -> f64 {
    0.5
}

#[derive(Deserialize, Default, Clone, Copy)]
#[serde(rename_all = "snake_case")]
pub(super) enum RawIntegrator {
    #[default]
    Euler,
    Rk4,
}
