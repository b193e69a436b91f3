//! Reading and writing meshes as OBJ (via `tobj`) and PLY (via `ply-rs-bw`).
//!
//! Readers take the whole file into memory first, so an unreadable path, a
//! directory or an empty file gets a clear error before any parsing. Polygons
//! are split into triangle fans (convex polygons only come out right).
//! Normals from the file are used where every face supplies them, averaged
//! per vertex; otherwise they are computed (see
//! [`angle_weighted_normals`](crate::mesh::angle_weighted_normals)).
//!
//! Writers keep full double precision, so a mesh written and read back has
//! bit-identical positions, and write to a temporary file that is renamed
//! into place, so a failure never leaves half a file.

use crate::mesh::{apply_weld, weld_map, Mesh};
use crate::MeshError;
use glam::DVec3;
use ply_rs_bw::parser::{ParseError, Parser, Reader};
use ply_rs_bw::ply::{
    Addable, BeginList, ElementDef, Encoding, Ply, PropertyAccess, PropertyAccessResult,
    PropertyDef, PropertyType, ScalarType,
};
use ply_rs_bw::writer::Writer;
use std::io::Write as _;
use std::path::Path;

/// Byte layout of a written PLY file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlyEncoding {
    /// Human-readable text.
    Ascii,
    /// Binary, little-endian (the common choice).
    BinaryLittleEndian,
    /// Binary, big-endian.
    BinaryBigEndian,
}

enum Format {
    Obj,
    Ply,
}

fn format_of(path: &Path) -> Result<Format, MeshError> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "obj" => Ok(Format::Obj),
        "ply" => Ok(Format::Ply),
        _ => Err(MeshError::UnknownExtension {
            path: path.display().to_string(),
            extension: ext,
        }),
    }
}

/// Read a whole input file of at most `max_bytes`, refusing what is not a
/// regular file (a device such as `/dev/zero`, a pipe, a directory) and a
/// file larger than the limit before reading it, so that no input can make
/// a reader allocate without bound. One reader for every input file of
/// eikon: scenes, meshes, VDB volumes, environment maps.
pub fn read_file(path: &Path, max_bytes: u64) -> std::io::Result<Vec<u8>> {
    use std::io::{Error, ErrorKind, Read};
    let file = std::fs::File::open(path)?;
    let meta = file.metadata()?;
    if !meta.is_file() {
        return Err(Error::new(
            ErrorKind::InvalidInput,
            "not a regular file (a device, pipe or directory)",
        ));
    }
    let too_big = || {
        Error::new(
            ErrorKind::InvalidData,
            format!("larger than the {max_bytes} bytes such a file may hold"),
        )
    };
    if meta.len() > max_bytes {
        return Err(too_big());
    }
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    // `take` keeps a file that grows while being read within the limit.
    file.take(max_bytes + 1).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max_bytes {
        return Err(too_big());
    }
    Ok(bytes)
}

/// The largest mesh file read (OBJ or PLY).
pub const MAX_MESH_BYTES: u64 = 4 << 30;

fn read(path: &Path) -> Result<Vec<u8>, MeshError> {
    let bytes = read_file(path, MAX_MESH_BYTES).map_err(|source| MeshError::Read {
        path: path.display().to_string(),
        source,
    })?;
    if bytes.is_empty() {
        return Err(MeshError::EmptyFile {
            name: path.display().to_string(),
        });
    }
    Ok(bytes)
}

/// Loads an `.obj` or `.ply` file (by extension, any case).
pub fn load(path: impl AsRef<Path>) -> Result<Mesh, MeshError> {
    let path = path.as_ref();
    match format_of(path)? {
        Format::Obj => load_obj(path),
        Format::Ply => load_ply(path),
    }
}

/// Loads a Wavefront OBJ file; see [`parse_obj`].
pub fn load_obj(path: impl AsRef<Path>) -> Result<Mesh, MeshError> {
    let path = path.as_ref();
    parse_obj(&read(path)?, &path.display().to_string())
}

/// Loads a PLY file (ASCII or binary); see [`parse_ply`].
pub fn load_ply(path: impl AsRef<Path>) -> Result<Mesh, MeshError> {
    let path = path.as_ref();
    parse_ply(&read(path)?, &path.display().to_string())
}

/// Lines of an OBJ file with their 1-based numbers.
fn obj_lines(bytes: &[u8]) -> impl Iterator<Item = (usize, &str)> {
    bytes.split(|&b| b == b'\n').enumerate().map(|(i, l)| {
        let s = std::str::from_utf8(l).unwrap_or("");
        (i + 1, s.trim())
    })
}

/// Whether the file has faces and every face corner names a normal
/// (`v//vn` or `v/vt/vn`). tobj invents a normal for corners without one, so
/// file normals are trusted only when none is missing.
fn obj_faces_all_have_normals(bytes: &[u8]) -> bool {
    let mut any = false;
    for (_, line) in obj_lines(bytes) {
        let mut tokens = line.split_whitespace();
        if tokens.next() != Some("f") {
            continue;
        }
        any = true;
        for corner in tokens {
            let parts: Vec<&str> = corner.split('/').collect();
            if parts.len() != 3 || parts[2].is_empty() {
                return false;
            }
        }
    }
    any
}

/// The first `v` line with a non-finite coordinate: (line, vertex number
/// counting from 0, coordinates).
fn find_non_finite_obj_vertex(bytes: &[u8]) -> Option<(usize, usize, [f64; 3])> {
    let mut count = 0;
    for (number, line) in obj_lines(bytes) {
        let mut tokens = line.split_whitespace();
        if tokens.next() != Some("v") {
            continue;
        }
        let c: Vec<f64> = tokens
            .take(3)
            .map(|t| t.parse::<f64>().unwrap_or(f64::NAN))
            .collect();
        if c.len() == 3 && c.iter().any(|x| !x.is_finite()) {
            return Some((number, count, [c[0], c[1], c[2]]));
        }
        count += 1;
    }
    None
}

/// Parses OBJ text; `name` (usually the path) appears in errors.
///
/// All objects and groups go into one mesh. Because tobj gives each group its
/// own copy of the vertices it uses, vertices at bit-identical positions are
/// merged (which is what makes a multi-group file closed again), and faces
/// that collapse under the merge (repeated corners) are dropped. Points and
/// lines are ignored; materials are not read.
pub fn parse_obj(bytes: &[u8], name: &str) -> Result<Mesh, MeshError> {
    if bytes.is_empty() {
        return Err(MeshError::EmptyFile {
            name: name.to_string(),
        });
    }
    // The struct update covers fields that tobj's optional features add, in
    // case another crate of the build turns them on.
    #[allow(clippy::needless_update)]
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: false,
        ignore_points: true,
        ignore_lines: true,
        ..Default::default()
    };
    let mut reader = bytes;
    let (models, _materials) = tobj::load_obj_buf(&mut reader, &options, |_| {
        Err(tobj::LoadError::OpenFileFailed)
    })
    .map_err(|e| MeshError::Parse {
        name: name.to_string(),
        format: "OBJ",
        message: e.to_string(),
    })?;
    let mut use_normals = obj_faces_all_have_normals(bytes);
    let mut positions: Vec<DVec3> = Vec::new();
    let mut triangles: Vec<[u32; 3]> = Vec::new();
    let mut normal_sum: Vec<DVec3> = Vec::new();
    for model in &models {
        let m = &model.mesh;
        let base = positions.len();
        positions.extend(
            m.positions
                .chunks_exact(3)
                .map(|c| DVec3::new(c[0], c[1], c[2])),
        );
        if positions.len() > u32::MAX as usize {
            return Err(MeshError::TooLarge {
                name: name.to_string(),
                count: positions.len(),
            });
        }
        triangles.extend(
            m.indices
                .chunks_exact(3)
                .map(|t| [0, 1, 2].map(|k| base as u32 + t[k])),
        );
        normal_sum.resize(positions.len(), DVec3::ZERO);
        if m.normals.is_empty() || m.normal_indices.len() != m.indices.len() {
            use_normals = false;
        }
        if use_normals {
            for (&v, &ni) in m.indices.iter().zip(&m.normal_indices) {
                let ni = ni as usize * 3;
                if let Some(c) = m.normals.get(ni..ni + 3) {
                    normal_sum[base + v as usize] +=
                        DVec3::new(c[0], c[1], c[2]).normalize_or_zero();
                }
            }
        }
    }
    if triangles.is_empty() {
        return Err(MeshError::NoTriangles {
            name: name.to_string(),
            detail: "; the file has no faces".into(),
        });
    }
    if positions.iter().any(|p| !p.is_finite()) {
        if let Some((line, index, position)) = find_non_finite_obj_vertex(bytes) {
            return Err(MeshError::NonFiniteVertex {
                name: format!("{name}:{line}"),
                index,
                position,
            });
        }
    }
    let remap = weld_map(&positions, 0.0);
    let normals = use_normals.then_some(normal_sum.as_slice());
    let (positions, normals, triangles, _) = apply_weld(&positions, normals, &triangles, &remap);
    if triangles.is_empty() {
        return Err(MeshError::NoTriangles {
            name: name.to_string(),
            detail: "; every face repeats a vertex".into(),
        });
    }
    let mut mesh = Mesh::new(name, positions, triangles)?;
    if let Some(n) = normals {
        mesh.override_normals(&n);
    }
    Ok(mesh)
}

/// One PLY element as we read or write it: a vertex (position, optional
/// normal) or a face (index list). Unknown properties are ignored.
#[derive(Clone, Debug, Default)]
struct PlyRecord {
    values: [f64; 6],
    indices: Vec<u32>,
    /// A negative index seen in the face list.
    negative: Option<i64>,
}

const VERTEX_PROPERTIES: [&str; 6] = ["x", "y", "z", "nx", "ny", "nz"];

fn is_index_list(name: &str) -> bool {
    name == "vertex_indices" || name == "vertex_index"
}

impl PlyRecord {
    fn set(&mut self, name: &str, v: f64) -> PropertyAccessResult {
        match VERTEX_PROPERTIES.iter().position(|p| *p == name) {
            Some(i) => {
                self.values[i] = v;
                PropertyAccessResult::Set
            }
            None => PropertyAccessResult::Ignored,
        }
    }

    fn set_signed(
        &mut self,
        name: &str,
        list: impl IntoIterator<Item = i64>,
    ) -> PropertyAccessResult {
        if !is_index_list(name) {
            return PropertyAccessResult::Ignored;
        }
        self.indices.clear();
        for i in list {
            match u32::try_from(i) {
                Ok(u) => self.indices.push(u),
                Err(_) => {
                    self.negative.get_or_insert(i);
                }
            }
        }
        PropertyAccessResult::Set
    }
}

impl PropertyAccess for PlyRecord {
    fn new() -> Self {
        Self::default()
    }
    fn set_char(&mut self, name: &str, v: i8) -> PropertyAccessResult {
        self.set(name, v.into())
    }
    fn set_uchar(&mut self, name: &str, v: u8) -> PropertyAccessResult {
        self.set(name, v.into())
    }
    fn set_short(&mut self, name: &str, v: i16) -> PropertyAccessResult {
        self.set(name, v.into())
    }
    fn set_ushort(&mut self, name: &str, v: u16) -> PropertyAccessResult {
        self.set(name, v.into())
    }
    fn set_int(&mut self, name: &str, v: i32) -> PropertyAccessResult {
        self.set(name, v.into())
    }
    fn set_uint(&mut self, name: &str, v: u32) -> PropertyAccessResult {
        self.set(name, v.into())
    }
    fn set_float(&mut self, name: &str, v: f32) -> PropertyAccessResult {
        self.set(name, v.into())
    }
    fn set_double(&mut self, name: &str, v: f64) -> PropertyAccessResult {
        self.set(name, v)
    }
    fn begin_list_uint(&mut self, name: &str, _len: usize) -> BeginList<'_, u32> {
        if is_index_list(name) {
            BeginList::Fill(&mut self.indices)
        } else {
            BeginList::UseSetter
        }
    }
    fn set_list_uchar(&mut self, name: &str, v: Vec<u8>) -> PropertyAccessResult {
        self.set_signed(name, v.into_iter().map(i64::from))
    }
    fn set_list_char(&mut self, name: &str, v: Vec<i8>) -> PropertyAccessResult {
        self.set_signed(name, v.into_iter().map(i64::from))
    }
    fn set_list_ushort(&mut self, name: &str, v: Vec<u16>) -> PropertyAccessResult {
        self.set_signed(name, v.into_iter().map(i64::from))
    }
    fn set_list_short(&mut self, name: &str, v: Vec<i16>) -> PropertyAccessResult {
        self.set_signed(name, v.into_iter().map(i64::from))
    }
    fn set_list_int(&mut self, name: &str, v: Vec<i32>) -> PropertyAccessResult {
        self.set_signed(name, v.into_iter().map(i64::from))
    }
    fn set_list_uint(&mut self, name: &str, v: Vec<u32>) -> PropertyAccessResult {
        self.set_signed(name, v.into_iter().map(i64::from))
    }
    fn get_double(&self, name: &str) -> Option<f64> {
        VERTEX_PROPERTIES
            .iter()
            .position(|p| *p == name)
            .map(|i| self.values[i])
    }
    fn get_list_uint(&self, name: &str) -> Option<&[u32]> {
        is_index_list(name).then_some(self.indices.as_slice())
    }
}

/// Parses a PLY file (ASCII or binary of either byte order); `name` (usually
/// the path) appears in errors.
///
/// Needs a `vertex` element with `x`, `y`, `z` (any numeric type; `nx`,
/// `ny`, `nz` are used when all present) and a `face` element with a
/// `vertex_indices` (or `vertex_index`) list. Other elements and properties
/// are skipped. Vertices are not merged: PLY files share them by index.
pub fn parse_ply(bytes: &[u8], name: &str) -> Result<Mesh, MeshError> {
    if bytes.is_empty() {
        return Err(MeshError::EmptyFile {
            name: name.to_string(),
        });
    }
    let parse_error = |e: ParseError| MeshError::Parse {
        name: name.to_string(),
        format: "PLY",
        message: e.to_string(),
    };
    let bad = |message: String| MeshError::Parse {
        name: name.to_string(),
        format: "PLY",
        message,
    };
    let mut reader = Reader::new(bytes);
    let parser = Parser::<PlyRecord>::new();
    let header = parser.read_header(&mut reader).map_err(parse_error)?;
    let header_lines = reader.line();
    let vertex = header
        .elements
        .get("vertex")
        .ok_or_else(|| bad("there is no \"vertex\" element".into()))?;
    for p in &VERTEX_PROPERTIES[..3] {
        if !vertex.properties.contains_key(*p) {
            return Err(bad(format!("the vertex element has no property \"{p}\"")));
        }
    }
    let has_normals = VERTEX_PROPERTIES[3..]
        .iter()
        .all(|p| vertex.properties.contains_key(*p));
    let Some(face) = header.elements.get("face") else {
        return Err(MeshError::NoTriangles {
            name: name.to_string(),
            detail: "; the file has no \"face\" element (a point cloud?)".into(),
        });
    };
    if !face.properties.keys().any(|k| is_index_list(k)) {
        return Err(bad(
            "the face element has no \"vertex_indices\" list property".into(),
        ));
    }
    // Every record takes bytes, so the header's counts cannot exceed what
    // follows it: refuse them before reading (a 3 KB file announcing 2^31
    // records of an element without properties made the reader loop and
    // allocate without end).
    let remaining = reader.get_ref().len() as u64;
    let mut need = 0u64;
    for (element, def) in &header.elements {
        let least = min_record_bytes(def, header.encoding);
        need = need.saturating_add((def.count as u64).saturating_mul(least));
        // One byte of slack: the last ASCII line may lack its newline.
        if need > remaining + 1 {
            return Err(bad(format!(
                "the header announces {} \"{element}\" record(s) of at least {least} byte(s) each, more than the {remaining} bytes after the header hold",
                def.count
            )));
        }
    }
    let vertex_first = header.elements.get_index_of("vertex") == Some(0);
    let mut vertices = Vec::new();
    let mut faces = Vec::new();
    for (element, def) in &header.elements {
        let records = parser
            .read_payload_for_element(&mut reader, def, &header)
            .map_err(parse_error)?;
        match element.as_str() {
            "vertex" => vertices = records,
            "face" => faces = records,
            _ => {}
        }
    }
    let positions: Vec<DVec3> = vertices
        .iter()
        .map(|r| DVec3::new(r.values[0], r.values[1], r.values[2]))
        .collect();
    if let Some(i) = positions.iter().position(|p| !p.is_finite()) {
        // In an ASCII file whose vertices come first, vertex i is a known line.
        let at = if header.encoding == Encoding::Ascii && vertex_first {
            format!("{name}:{}", header_lines + 1 + i)
        } else {
            name.to_string()
        };
        return Err(MeshError::NonFiniteVertex {
            name: at,
            index: i,
            position: positions[i].to_array(),
        });
    }
    let mut triangles = Vec::with_capacity(faces.len());
    for (f, r) in faces.iter().enumerate() {
        if let Some(v) = r.negative {
            return Err(MeshError::IndexOutOfRange {
                name: name.to_string(),
                face: f,
                vertex: v as u64,
                count: positions.len(),
            });
        }
        if r.indices.len() < 3 {
            return Err(MeshError::ShortFace {
                name: name.to_string(),
                face: f,
                count: r.indices.len(),
            });
        }
        if let Some(&v) = r.indices.iter().find(|&&v| v as usize >= positions.len()) {
            return Err(MeshError::IndexOutOfRange {
                name: name.to_string(),
                face: f,
                vertex: v as u64,
                count: positions.len(),
            });
        }
        for k in 1..r.indices.len() - 1 {
            triangles.push([r.indices[0], r.indices[k], r.indices[k + 1]]);
        }
    }
    let mut mesh = Mesh::new(name, positions, triangles)?;
    if has_normals {
        let normals: Vec<DVec3> = vertices
            .iter()
            .map(|r| DVec3::new(r.values[3], r.values[4], r.values[5]))
            .collect();
        mesh.override_normals(&normals);
    }
    Ok(mesh)
}

/// The fewest bytes a record of `def` takes: in binary its scalars and the
/// counts of its lists, in ASCII a character and a separator per property;
/// at least one byte (an ASCII line, or binary data).
fn min_record_bytes(def: &ElementDef, encoding: Encoding) -> u64 {
    let size = |t: &ScalarType| match t {
        ScalarType::Char | ScalarType::UChar => 1,
        ScalarType::Short | ScalarType::UShort => 2,
        ScalarType::Int | ScalarType::UInt | ScalarType::Float => 4,
        ScalarType::Double => 8,
    };
    let bytes: u64 = def
        .properties
        .values()
        .map(|p| match (encoding, &p.data_type) {
            (Encoding::Ascii, _) => 2,
            (_, PropertyType::Scalar(t) | PropertyType::List(t, _)) => size(t),
        })
        .sum();
    bytes.max(1)
}

/// Writes `bytes` beside `path` and renames the result into place.
fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), MeshError> {
    let error = |source| MeshError::Write {
        path: path.display().to_string(),
        source,
    };
    let file_name = path.file_name().ok_or_else(|| {
        error(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "the path names no file",
        ))
    })?;
    let tmp = path.with_file_name(format!(
        ".{}.{}.tmp",
        file_name.to_string_lossy(),
        std::process::id()
    ));
    let result = std::fs::write(&tmp, bytes).and_then(|()| std::fs::rename(&tmp, path));
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(error(e));
    }
    Ok(())
}

/// A header-safe one-line version of the mesh name.
fn comment(mesh: &Mesh) -> String {
    mesh.name().replace(['\n', '\r'], " ")
}

/// The OBJ text of `mesh`: `v`, `vn` and `f v//vn` lines, coordinates in
/// shortest round-trip form.
pub fn obj_bytes(mesh: &Mesh) -> Vec<u8> {
    let mut out = Vec::with_capacity(64 * mesh.vertex_count() + 32 * mesh.triangle_count());
    // Writing to a Vec cannot fail.
    let _ = writeln!(out, "# eikon-mesh: {}", comment(mesh));
    for p in mesh.positions() {
        let _ = writeln!(out, "v {:?} {:?} {:?}", p.x, p.y, p.z);
    }
    for n in mesh.normals() {
        let _ = writeln!(out, "vn {:?} {:?} {:?}", n.x, n.y, n.z);
    }
    for t in mesh.triangles() {
        let [a, b, c] = t.map(|v| v as u64 + 1);
        let _ = writeln!(out, "f {a}//{a} {b}//{b} {c}//{c}");
    }
    out
}

/// The PLY file of `mesh`: double `x y z nx ny nz` per vertex and a
/// `uchar`-counted `uint` list per face.
pub fn ply_bytes(mesh: &Mesh, encoding: PlyEncoding) -> Result<Vec<u8>, MeshError> {
    let mut ply = Ply::<PlyRecord>::new();
    ply.header.encoding = match encoding {
        PlyEncoding::Ascii => Encoding::Ascii,
        PlyEncoding::BinaryLittleEndian => Encoding::BinaryLittleEndian,
        PlyEncoding::BinaryBigEndian => Encoding::BinaryBigEndian,
    };
    ply.header
        .comments
        .push(format!("eikon-mesh: {}", comment(mesh)));
    let mut vertex = ElementDef::new("vertex".into());
    for p in VERTEX_PROPERTIES {
        vertex.properties.add(PropertyDef::new(
            p.into(),
            PropertyType::Scalar(ScalarType::Double),
        ));
    }
    ply.header.elements.add(vertex);
    let mut face = ElementDef::new("face".into());
    face.properties.add(PropertyDef::new(
        "vertex_indices".into(),
        PropertyType::List(ScalarType::UChar, ScalarType::UInt),
    ));
    ply.header.elements.add(face);
    let vertices = mesh
        .positions()
        .iter()
        .zip(mesh.normals())
        .map(|(p, n)| PlyRecord {
            values: [p.x, p.y, p.z, n.x, n.y, n.z],
            ..Default::default()
        })
        .collect();
    let faces = mesh
        .triangles()
        .iter()
        .map(|t| PlyRecord {
            indices: t.to_vec(),
            ..Default::default()
        })
        .collect();
    ply.payload.insert("vertex".into(), vertices);
    ply.payload.insert("face".into(), faces);
    let mut out = Vec::new();
    Writer::new()
        .write_ply(&mut out, &mut ply)
        .map_err(|source| MeshError::Write {
            path: mesh.name().to_string(),
            source,
        })?;
    Ok(out)
}

/// Writes `mesh` as OBJ (see [`obj_bytes`]).
pub fn write_obj(mesh: &Mesh, path: impl AsRef<Path>) -> Result<(), MeshError> {
    write_atomic(path.as_ref(), &obj_bytes(mesh))
}

/// Writes `mesh` as PLY (see [`ply_bytes`]).
pub fn write_ply(
    mesh: &Mesh,
    path: impl AsRef<Path>,
    encoding: PlyEncoding,
) -> Result<(), MeshError> {
    write_atomic(path.as_ref(), &ply_bytes(mesh, encoding)?)
}

/// Writes `mesh` in the format its extension names; PLY is binary
/// little-endian.
pub fn save(mesh: &Mesh, path: impl AsRef<Path>) -> Result<(), MeshError> {
    let path = path.as_ref();
    match format_of(path)? {
        Format::Obj => write_obj(mesh, path),
        Format::Ply => write_ply(mesh, path, PlyEncoding::BinaryLittleEndian),
    }
}
