//! Animated scenes: an `[animation]` table of frames and keyframed tracks
//! on a scene's own fields (documented in `docs/SCENES.md`, "Animation").
//!
//! A track names a field of the scene file (`light[0].position`,
//! `object[1].shape.rotation`, `camera.fov`, ...) and gives its value at
//! key frames; between keys the value is interpolated, linearly or by a
//! Catmull-Rom spline. A frame is the scene file with every tracked field
//! set to its value at that frame, checked like any static scene: so a
//! frame equals the static scene that writes those values, bit for bit,
//! and every check and error of a static scene applies to each frame. A
//! scene without `[animation]` is a one-frame animation.

use crate::error::{Error, Result};
use crate::scene::locate::{deserialize, Checker, Seg};
use crate::scene::{read_text, GridOverride, Scene};
use serde::Deserialize;
use std::path::Path;

/// The most frames an animation may have.
pub const MAX_FRAMES: usize = 1_000_000;

/// How a track's value goes from one key to the next.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Interpolation {
    /// Straight from key to key.
    Linear,
    /// A Catmull-Rom spline through the keys: a cubic Hermite segment
    /// between each pair, whose tangent at a key is the slope between its
    /// neighbours (one-sided at the first and last key). Continuous in
    /// value and slope; two keys give the straight line.
    Smooth,
}

/// One key: a frame (fractional frames allowed) and the value there.
#[derive(Clone, Debug, PartialEq)]
pub struct Key {
    /// The frame.
    pub frame: f64,
    /// The value: one number, or three for a vector or colour.
    pub value: Vec<f64>,
}

/// A keyframed field.
#[derive(Clone, Debug)]
pub struct Track {
    /// The field, as written (`light[0].position`).
    pub field: String,
    /// The field's path.
    path: Vec<Part>,
    /// How values are interpolated between keys.
    pub interpolation: Interpolation,
    /// Keys in increasing frame order.
    pub keys: Vec<Key>,
}

/// One step of a track's field path.
#[derive(Clone, Debug, PartialEq)]
enum Part {
    Key(String),
    Index(usize),
}

/// A scene with its frames: what `--frames` runs over.
#[derive(Clone, Debug)]
pub struct Animation {
    /// Frames, numbered from 0.
    pub frames: usize,
    /// Frames per second (for image sequences and animated previews).
    pub fps: f64,
    /// The tracks, in file order.
    pub tracks: Vec<Track>,
    origin: String,
    text: String,
    grid: GridOverride,
}

#[derive(Deserialize)]
struct RawDocument {
    #[serde(default)]
    animation: Option<RawAnimation>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawAnimation {
    frames: u64,
    #[serde(default = "default_fps")]
    fps: f64,
    #[serde(default, rename = "track")]
    tracks: Vec<RawTrack>,
}

fn default_fps() -> f64 {
    24.0
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTrack {
    field: String,
    #[serde(default = "default_interpolation")]
    interpolation: Interpolation,
    keys: Vec<RawKey>,
}

fn default_interpolation() -> Interpolation {
    Interpolation::Linear
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawKey {
    frame: f64,
    value: RawValue,
}

#[derive(Deserialize)]
#[serde(untagged, expecting = "expected a number or [x, y, z]")]
enum RawValue {
    Scalar(f64),
    Vector([f64; 3]),
}

/// What a field holds: one number or three.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Scalar,
    Vector,
}

/// The fields a track may animate: `(section, field, kind)`. Lights and the
/// camera move without touching the medium; objects' placement and size
/// rebuild it.
const ANIMATABLE: &[(&str, &str, Kind)] = &[
    ("light", "position", Kind::Vector),
    ("light", "direction", Kind::Vector),
    ("light", "power", Kind::Vector),
    ("light", "angle", Kind::Scalar),
    ("light", "falloff", Kind::Scalar),
    ("camera", "position", Kind::Vector),
    ("camera", "target", Kind::Vector),
    ("camera", "up", Kind::Vector),
    ("camera", "fov", Kind::Scalar),
    ("shape", "center", Kind::Vector),
    ("shape", "base", Kind::Vector),
    ("shape", "point", Kind::Vector),
    ("shape", "normal", Kind::Vector),
    ("shape", "translate", Kind::Vector),
    ("shape", "rotation", Kind::Vector),
    ("shape", "size", Kind::Vector),
    ("shape", "radii", Kind::Vector),
    ("shape", "scale", Kind::Scalar),
    ("shape", "radius", Kind::Scalar),
    ("shape", "height", Kind::Scalar),
    ("shape", "major_radius", Kind::Scalar),
    ("shape", "minor_radius", Kind::Scalar),
    ("shape", "edge", Kind::Scalar),
];

/// Whether scene `text` has an `[animation]` table (without checking it).
pub(crate) fn is_animated(text: &str) -> bool {
    toml_edit::ImDocument::parse(text).is_ok_and(|d| d.get("animation").is_some())
}

impl Animation {
    /// Read a scene file as an animation (a static scene is one frame).
    pub fn load_with(path: &Path, grid: &GridOverride) -> Result<Animation> {
        Animation::parse_with(&read_text(path)?, &path.display().to_string(), grid)
    }

    /// Parse scene `text` as an animation, `origin` naming it in errors and
    /// `grid` applied to every frame. Checks the `[animation]` table and
    /// that every tracked field exists in the scene with a value of its
    /// kind (each frame's scene is checked when it is made).
    pub fn parse_with(text: &str, origin: &str, grid: &GridOverride) -> Result<Animation> {
        let raw: RawDocument = deserialize(text, origin)?;
        let mut out = Animation {
            frames: 1,
            fps: default_fps(),
            tracks: Vec::new(),
            origin: origin.to_string(),
            text: text.to_string(),
            grid: *grid,
        };
        let Some(a) = raw.animation else {
            return Ok(out);
        };
        let c = Checker { origin, text };
        use Seg::{Index as I, Key as K};
        let at = |k| [K("animation"), K(k)];
        if a.frames == 0 || a.frames > MAX_FRAMES as u64 {
            return Err(c.err(
                &at("frames"),
                format!("must lie in 1..={MAX_FRAMES}, got {}", a.frames),
            ));
        }
        if !(a.fps.is_finite() && a.fps > 0.0) {
            return Err(c.err(&at("fps"), format!("must be > 0, got {}", a.fps)));
        }
        out.frames = a.frames as usize;
        out.fps = a.fps;
        let doc = toml_edit::ImDocument::parse(text).map_err(|e| {
            c.err(
                &[],
                format!("not TOML: {}", e.message().replace('\n', ": ")),
            )
        })?;
        for (t, raw) in a.tracks.iter().enumerate() {
            let tp = |k| [K("animation"), K("track"), I(t), K(k)];
            let (path, kind) = field_path(&raw.field).map_err(|m| c.err(&tp("field"), m))?;
            if let Some(found) = lookup(doc.as_item(), &path) {
                let have = match found {
                    toml_edit::Item::Value(v) if v.as_array().is_some_and(|a| a.len() == 3) => {
                        Some(Kind::Vector)
                    }
                    toml_edit::Item::Value(v) if v.is_float() || v.is_integer() => {
                        Some(Kind::Scalar)
                    }
                    _ => None,
                };
                if have != Some(kind) {
                    return Err(c.err(
                        &tp("field"),
                        format!(
                            "`{}` in the scene is not {} to animate",
                            raw.field,
                            kind.words()
                        ),
                    ));
                }
            } else if !lookup(doc.as_item(), &path[..path.len() - 1]).is_some_and(is_table) {
                return Err(c.err(
                    &tp("field"),
                    format!("the scene has no `{}` table to animate", parent(&raw.field)),
                ));
            }
            if raw.keys.is_empty() {
                return Err(c.err(&tp("keys"), "a track needs at least one key"));
            }
            let mut keys = Vec::with_capacity(raw.keys.len());
            for (k, key) in raw.keys.iter().enumerate() {
                let kp = |f| [K("animation"), K("track"), I(t), K("keys"), I(k), K(f)];
                let last = (out.frames - 1) as f64;
                if !(key.frame.is_finite() && (0.0..=last).contains(&key.frame)) {
                    return Err(c.err(
                        &kp("frame"),
                        format!(
                            "key frame {} is out of range: frames are 0 to {last}",
                            key.frame
                        ),
                    ));
                }
                if let Some(prev) = keys.last().map(|p: &Key| p.frame) {
                    if key.frame <= prev {
                        return Err(c.err(
                            &kp("frame"),
                            format!(
                                "keys must be in increasing frame order: {} follows {prev}",
                                key.frame
                            ),
                        ));
                    }
                }
                let value = match (&key.value, kind) {
                    (RawValue::Scalar(v), Kind::Scalar) => vec![*v],
                    (RawValue::Vector(v), Kind::Vector) => v.to_vec(),
                    _ => {
                        return Err(c.err(
                            &kp("value"),
                            format!("`{}` takes {}", raw.field, kind.words()),
                        ))
                    }
                };
                if !value.iter().all(|v| v.is_finite()) {
                    return Err(c.err(&kp("value"), "must be finite (not NaN or infinity)"));
                }
                keys.push(Key {
                    frame: key.frame,
                    value,
                });
            }
            if out.tracks.iter().any(|o| o.path == path) {
                return Err(c.err(&tp("field"), format!("`{}` has two tracks", raw.field)));
            }
            out.tracks.push(Track {
                field: raw.field.clone(),
                path,
                interpolation: raw.interpolation,
                keys,
            });
        }
        Ok(out)
    }

    /// The scene file's text as read.
    pub fn text(&self) -> &str {
        &self.text
    }

    /// Whether any track moves or resizes an object, so that the medium
    /// differs between frames (lights and the camera leave it as it is).
    pub fn moves_medium(&self) -> bool {
        self.tracks
            .iter()
            .any(|t| !matches!(&t.path[0], Part::Key(k) if k == "light" || k == "camera"))
    }

    /// The scene file's text at frame `f`: every tracked field set to its
    /// value there, the rest as written (so line numbers stay).
    pub fn frame_text(&self, f: usize) -> String {
        if self.tracks.is_empty() {
            return self.text.clone();
        }
        let mut doc: toml_edit::DocumentMut = self.text.parse().expect("parsed when loaded");
        for t in &self.tracks {
            let v = t.at(f as f64);
            let value = match v.as_slice() {
                [x] => toml_edit::Value::from(*x),
                xs => toml_edit::Value::Array(xs.iter().copied().collect()),
            };
            set(doc.as_item_mut(), &t.path, value);
        }
        doc.to_string()
    }

    /// The scene at frame `f` (0-based), checked like a static scene; an
    /// error names the frame.
    pub fn frame(&self, f: usize) -> Result<Scene> {
        if f >= self.frames {
            return Err(Error::Invalid {
                at: crate::error::Location {
                    file: self.origin.clone(),
                    line_column: None,
                    field: "animation.frames".into(),
                },
                message: format!(
                    "frame {f} does not exist: frames are 0 to {}",
                    self.frames - 1
                ),
            });
        }
        let text = self.frame_text(f);
        Scene::parse_static(&text, &self.origin, &self.grid).map_err(|e| match e {
            Error::Invalid { at, message } if !self.tracks.is_empty() => Error::Invalid {
                at,
                message: format!("at frame {f}: {message}"),
            },
            e => e,
        })
    }
}

impl Track {
    /// The value at frame `t`: the first key's before it, the last key's
    /// after it, interpolated between.
    pub fn at(&self, t: f64) -> Vec<f64> {
        let k = &self.keys;
        let first = &k[0];
        let last = &k[k.len() - 1];
        if t <= first.frame {
            return first.value.clone();
        }
        if t >= last.frame {
            return last.value.clone();
        }
        // The segment [k[i], k[i + 1]) holding t.
        let i = k.partition_point(|key| key.frame <= t) - 1;
        let (a, b) = (&k[i], &k[i + 1]);
        let dt = b.frame - a.frame;
        let u = (t - a.frame) / dt;
        match self.interpolation {
            Interpolation::Linear => (0..a.value.len())
                .map(|c| a.value[c] + u * (b.value[c] - a.value[c]))
                .collect(),
            Interpolation::Smooth => {
                // Tangents per frame: centred differences over the
                // neighbouring keys, one-sided at the ends.
                let slope = |j: usize, c: usize| {
                    let lo = j.saturating_sub(1);
                    let hi = (j + 1).min(k.len() - 1);
                    (k[hi].value[c] - k[lo].value[c]) / (k[hi].frame - k[lo].frame)
                };
                let (u2, u3) = (u * u, u * u * u);
                let h00 = 2.0 * u3 - 3.0 * u2 + 1.0;
                let h10 = u3 - 2.0 * u2 + u;
                let h01 = -2.0 * u3 + 3.0 * u2;
                let h11 = u3 - u2;
                (0..a.value.len())
                    .map(|c| {
                        h00 * a.value[c]
                            + h10 * dt * slope(i, c)
                            + h01 * b.value[c]
                            + h11 * dt * slope(i + 1, c)
                    })
                    .collect()
            }
        }
    }
}

impl Kind {
    fn words(self) -> &'static str {
        match self {
            Kind::Scalar => "one number",
            Kind::Vector => "three numbers [x, y, z]",
        }
    }
}

/// The text before the last `.` of a field path.
fn parent(field: &str) -> &str {
    field.rsplit_once('.').map_or(field, |(p, _)| p)
}

/// Parse `light[0].position` into its parts, checking it is animatable.
fn field_path(field: &str) -> std::result::Result<(Vec<Part>, Kind), String> {
    let mut parts = Vec::new();
    for piece in field.split('.') {
        let (name, rest) = piece.split_once('[').unwrap_or((piece, ""));
        if name.is_empty() || !name.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'_') {
            return Err(format!(
                "`{field}` is not a field path such as light[0].position"
            ));
        }
        parts.push(Part::Key(name.to_string()));
        if !rest.is_empty() {
            let i = rest
                .strip_suffix(']')
                .and_then(|n| n.parse::<usize>().ok())
                .ok_or_else(|| format!("`{field}`: `[{rest}` is not an index such as [0]"))?;
            parts.push(Part::Index(i));
        }
    }
    fn section(p: &[Part]) -> Option<(&'static str, &str)> {
        match p {
            [Part::Key(l), Part::Index(_), Part::Key(f)] if l == "light" => Some(("light", f)),
            [Part::Key(c), Part::Key(f)] if c == "camera" => Some(("camera", f)),
            [Part::Key(o), Part::Index(_), Part::Key(s), Part::Key(f)]
                if o == "object" && s == "shape" =>
            {
                Some(("shape", f))
            }
            _ => None,
        }
    }
    let kind = section(&parts).and_then(|(section, f)| {
        ANIMATABLE
            .iter()
            .find(|(s, n, _)| *s == section && *n == f)
            .map(|(_, _, k)| *k)
    });
    match kind {
        Some(k) => Ok((parts, k)),
        None => Err(format!(
            "`{field}` cannot animate: tracks take a light's position, direction, power, angle or falloff (light[i].position), the camera's position, target, up or fov (camera.fov), or an object's placement and size (object[i].shape.center, .rotation, .translate, .scale, .radius, .size, ...)"
        )),
    }
}

/// Whether `item` is a table (`[x]`, `[[x]]` entry or `{ ... }`): where
/// a tracked field can be set.
fn is_table(item: &toml_edit::Item) -> bool {
    matches!(
        item,
        toml_edit::Item::Table(_) | toml_edit::Item::Value(toml_edit::Value::InlineTable(_))
    )
}

fn lookup<'a>(item: &'a toml_edit::Item, path: &[Part]) -> Option<&'a toml_edit::Item> {
    let mut item = item;
    for p in path {
        item = match p {
            Part::Key(k) => item.get(k.as_str())?,
            Part::Index(i) => item.get(*i)?,
        };
    }
    Some(item)
}

/// Set the field at `path` (its parent exists: checked when loaded).
fn set(root: &mut toml_edit::Item, path: &[Part], value: toml_edit::Value) {
    let (last, head) = path.split_last().expect("a field path");
    let mut item = root;
    for p in head {
        item = match p {
            Part::Key(k) => item.get_mut(k.as_str()),
            Part::Index(i) => item.get_mut(*i),
        }
        .expect("checked when loaded");
    }
    let Part::Key(k) = last else {
        unreachable!("field paths end with a name")
    };
    match item {
        toml_edit::Item::Table(t) => {
            t.insert(k, toml_edit::Item::Value(value));
        }
        toml_edit::Item::Value(toml_edit::Value::InlineTable(t)) => {
            t.insert(k, value);
        }
        _ => unreachable!("a field's parent is a table"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn track(interpolation: Interpolation, keys: &[(f64, f64)]) -> Track {
        Track {
            field: "camera.fov".into(),
            path: vec![Part::Key("camera".into()), Part::Key("fov".into())],
            interpolation,
            keys: keys
                .iter()
                .map(|&(frame, v)| Key {
                    frame,
                    value: vec![v],
                })
                .collect(),
        }
    }

    #[test]
    fn linear_keys_and_between() {
        let t = track(
            Interpolation::Linear,
            &[(0.0, 10.0), (4.0, 30.0), (10.0, 0.0)],
        );
        for (f, want) in [
            (-1.0, 10.0),
            (0.0, 10.0),
            (1.0, 15.0),
            (2.0, 20.0),
            (4.0, 30.0),
            (7.0, 15.0),
            (10.0, 0.0),
            (12.0, 0.0),
        ] {
            assert_eq!(t.at(f), [want], "frame {f}");
        }
    }

    #[test]
    fn smooth_is_catmull_rom() {
        // Uniform keys 0, 1, 2, 3 at frames 0, 10, 20, 30 with values
        // 0, 1, 4, 9. Segment 10..20: tangents per frame m1 = (4 - 0) / 20
        // = 0.2 and m2 = (9 - 1) / 20 = 0.4; at u = 1/2 the Hermite basis
        // gives 0.5 * 1 + 0.125 * 10 * 0.2 + 0.5 * 4 - 0.125 * 10 * 0.4 =
        // 2.25 (the parabola's 2.25 too: Catmull-Rom is exact on it inside).
        let t = track(
            Interpolation::Smooth,
            &[(0.0, 0.0), (10.0, 1.0), (20.0, 4.0), (30.0, 9.0)],
        );
        assert_eq!(t.at(10.0), [1.0]);
        assert_eq!(t.at(20.0), [4.0]);
        assert!((t.at(15.0)[0] - 2.25).abs() < 1e-12, "{:?}", t.at(15.0));
        // u = 1/4 on 10..20: h00 = 27/32, h10 = 9/64, h01 = 5/32, h11 = -3/64:
        // 27/32 + 9/64 * 2 + 5/32 * 4 - 3/64 * 4 = 1.5625 = 12.5^2 / 100.
        assert!((t.at(12.5)[0] - 1.5625).abs() < 1e-12, "{:?}", t.at(12.5));
        // First segment: one-sided tangent at the first key m0 = 1/10,
        // m1 = 0.2: at u = 1/2, 0.125 * 10 * 0.1 + 0.5 - 0.125 * 10 * 0.2
        // = 0.375.
        assert!((t.at(5.0)[0] - 0.375).abs() < 1e-12, "{:?}", t.at(5.0));
        // Two keys: the straight line.
        let two = track(Interpolation::Smooth, &[(0.0, 2.0), (8.0, 6.0)]);
        for f in [0.0, 1.0, 3.0, 6.5, 8.0] {
            assert!((two.at(f)[0] - (2.0 + f / 2.0)).abs() < 1e-12);
        }
    }

    #[test]
    fn paths_parse_and_unanimatable_fields_are_refused() {
        assert!(field_path("light[2].position").is_ok());
        assert!(field_path("object[0].shape.rotation").is_ok());
        assert_eq!(field_path("camera.fov").unwrap().1, Kind::Scalar);
        for bad in [
            "grid.resolution",
            "object[0].index",
            "light[x].power",
            "light.0.power",
            "",
        ] {
            assert!(field_path(bad).is_err(), "{bad}");
        }
    }

    const SCENE: &str = r#"
[grid]
resolution = 8
min = [-1, -1, -1]
max = [1, 1, 1]

[[object]]
shape = { type = "sphere", center = [0, 0, 0], radius = 0.5 }
index = 1.5

[[light]]
type = "point"
position = [0, 0.9, 0]
power = [1, 1, 1]

[camera]
position = [0, 0, 3]
target = [0, 0, 0]

[animation]
frames = 11
fps = 10

[[animation.track]]
field = "light[0].position"
keys = [{ frame = 0, value = [0, 0.9, 0] }, { frame = 10, value = [0.5, 0.9, -0.5] }]

[[animation.track]]
field = "object[0].shape.radius"
interpolation = "smooth"
keys = [{ frame = 0, value = 0.5 }, { frame = 10, value = 0.7 }]
"#;

    fn anim(text: &str) -> Result<Animation> {
        Animation::parse_with(text, "a.toml", &GridOverride::default())
    }

    #[test]
    fn frames_set_the_tracked_fields() {
        let a = anim(SCENE).unwrap();
        assert_eq!((a.frames, a.fps, a.tracks.len()), (11, 10.0, 2));
        assert!(a.moves_medium());
        let f4 = a.frame(4).unwrap();
        let crate::Light::Point { position, .. } = f4.lights[0] else {
            panic!()
        };
        assert_eq!(position.to_array(), [0.2, 0.9, -0.2]);
        let crate::Shape::Sphere { radius, .. } = f4.objects[0].shape else {
            panic!()
        };
        assert!((radius - 0.58).abs() < 1e-15, "{radius}");
        // Frame 0 is what a plain load gives.
        let s0 = Scene::parse(SCENE, "a.toml").unwrap();
        assert_eq!(
            format!("{:?}", s0.lights),
            format!("{:?}", a.frame(0).unwrap().lights)
        );
        // Lights only: the medium stays.
        let lights_only = SCENE.replace("object[0].shape.radius", "light[0].power");
        let lights_only = lights_only.replace("value = 0.5 }", "value = [1, 1, 1] }");
        let lights_only = lights_only.replace("value = 0.7 }", "value = [2, 2, 2] }");
        assert!(!anim(&lights_only).unwrap().moves_medium());
        // A static scene is one frame of itself.
        let plain = &SCENE[..SCENE.find("[animation]").unwrap()];
        let s = anim(plain).unwrap();
        assert_eq!((s.frames, s.tracks.len()), (1, 0));
        assert_eq!(s.frame_text(0), plain);
    }

    #[test]
    fn bad_tracks_are_located() {
        let cases = [
            (
                "frame = 10, value = [0.5",
                "frame = 11, value = [0.5",
                "out of range",
            ),
            (
                "frame = 10, value = [0.5",
                "frame = 0, value = [0.5",
                "increasing frame order",
            ),
            (
                "\"light[0].position\"",
                "\"light[3].position\"",
                "no `light[3]`",
            ),
            (
                "\"light[0].position\"",
                "\"grid.resolution\"",
                "cannot animate",
            ),
            (
                "\"light[0].position\"",
                "\"light[0].angle\"",
                "takes one number",
            ),
            ("value = 0.7", "value = [0.7, 1, 1]", "takes one number"),
            ("frames = 11", "frames = 0", "1..="),
            ("fps = 10", "fps = -1", "must be > 0"),
        ];
        for (from, to, want) in cases {
            let text = SCENE.replacen(from, to, 1);
            assert_ne!(text, SCENE, "{from}");
            let e = anim(&text)
                .and_then(|a| a.frame(3))
                .unwrap_err()
                .to_string();
            assert!(e.contains(want) && e.starts_with("a.toml:"), "{to}: {e}");
        }
        // Fuzz find: `light = [true]` made light[0] a boolean, whose field
        // the track then set (a panic); now refused where the track is.
        let (head, tail) = SCENE.split_at(SCENE.find("[[light]]").unwrap());
        let text = format!(
            "light = [true]\n{head}{}",
            &tail[tail.find("[camera]").unwrap()..]
        );
        assert!(toml_edit::ImDocument::parse(text.as_str()).unwrap()["light"][0].is_bool());
        let e = anim(&text).unwrap_err().to_string();
        assert!(e.contains("no `light[0]` table"), "{e}");
        // A frame whose values the scene refuses names the frame.
        let text = SCENE.replace("value = 0.7 }", "value = -0.7 }");
        let a = anim(&text).unwrap();
        assert!(a.frame(1).is_ok());
        let e = a.frame(10).unwrap_err().to_string();
        assert!(
            e.contains("at frame 10") && e.contains("object[0].shape.radius"),
            "{e}"
        );
    }
}
