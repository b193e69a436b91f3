//! The OpenVDB writer (file format 224): header, grid descriptors, and per
//! grid the metadata, transform, tree topology and leaf buffers, byte for
//! byte as OpenVDB's `io::Archive::write` lays them out.

use super::{Grid, GridData, Leaf, Result, Tree, VdbError, VdbValue, LEAF_SIZE};
use rayon::prelude::*;
use std::collections::{BTreeMap, BTreeSet};
use std::hash::{Hash, Hasher};
use std::io::Write;
use std::path::Path;

/// `OPENVDB_MAGIC`, written as a 64-bit integer.
pub(crate) const MAGIC: i64 = 0x5644_4220;
/// The file format version written (`OPENVDB_FILE_VERSION_MULTIPASS_IO`).
pub(crate) const FILE_VERSION: u32 = 224;
/// Library version recorded in the header (the format of OpenVDB 10.0).
const LIBRARY_VERSION: (u32, u32) = (10, 0);
/// Compression flags (`io::COMPRESS_*`).
pub(crate) const COMPRESS_ZIP: u32 = 0x1;
pub(crate) const COMPRESS_ACTIVE_MASK: u32 = 0x2;
pub(crate) const COMPRESS_BLOSC: u32 = 0x4;
/// Per-node metadata byte `NO_MASK_OR_INACTIVE_VALS`: every inactive value
/// is the background, so only active values follow.
const NO_MASK_OR_INACTIVE_VALS: u8 = 0;

/// How to write a file.
#[derive(Clone, Copy, Debug)]
pub struct WriteOptions {
    /// zlib-compress each node's values (`COMPRESS_ZIP`, at zlib's fastest
    /// level: 4% larger than its default level, 2.4 times faster). Smaller
    /// files, slower writes.
    pub zip: bool,
}

impl Default for WriteOptions {
    fn default() -> Self {
        Self { zip: true }
    }
}

/// What was written for one grid.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GridReport {
    /// Grid name.
    pub name: String,
    /// Tree type, with `_HalfFloat` when stored as half floats.
    pub grid_type: String,
    /// Active voxels (tiles counted voxel by voxel).
    pub active_voxels: u64,
    /// 8^3 leaves written.
    pub leaves: u64,
    /// Active tiles written (in 16^3 and 32^3 nodes).
    pub tiles: u64,
    /// Bytes the grid takes in the file.
    pub bytes: u64,
}

/// What was written.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct WriteReport {
    /// File size, bytes.
    pub bytes: u64,
    /// Per grid, in file order.
    pub grids: Vec<GridReport>,
}

/// Write `grids` as one OpenVDB file to `w`. Grid names must be unique and
/// non-empty. The file's unique tag (UUID) is derived from its contents, so
/// the same grids always give the same bytes.
pub fn write(w: &mut dyn Write, grids: &[Grid], options: &WriteOptions) -> Result<WriteReport> {
    let mut names = BTreeSet::new();
    for g in grids {
        if g.name.is_empty() {
            return Err(VdbError::Invalid("a grid has an empty name".into()));
        }
        if g.name.contains('\x1e') {
            return Err(VdbError::Invalid(format!(
                "grid name `{}` contains the record separator OpenVDB reserves",
                g.name.escape_debug()
            )));
        }
        if !names.insert(g.name.as_str()) {
            return Err(VdbError::Invalid(format!(
                "two grids are named `{}`",
                g.name
            )));
        }
        let t = &g.transform;
        if !(t.voxel_size.is_finite() && t.translation.is_finite())
            || t.voxel_size.min_element() <= 0.0
        {
            return Err(VdbError::Invalid(format!(
                "grid `{}`: the voxel size must be finite and > 0, got {} (translation {})",
                g.name, t.voxel_size, t.translation
            )));
        }
    }
    // Grids are independent: encode them in parallel, then lay them out.
    let bodies: Vec<(Vec<u8>, u64, Counts)> =
        grids.par_iter().map(|g| encode_grid(g, options)).collect();

    let mut hasher = std::collections::hash_map::DefaultHasher::new();
    for (b, ..) in &bodies {
        b.hash(&mut hasher);
    }
    let h1 = hasher.finish();
    "eikon".hash(&mut hasher);
    let h2 = hasher.finish();

    let mut head = Vec::new();
    head.extend_from_slice(&MAGIC.to_le_bytes());
    put_u32(&mut head, FILE_VERSION);
    put_u32(&mut head, LIBRARY_VERSION.0);
    put_u32(&mut head, LIBRARY_VERSION.1);
    head.push(1); // has grid offsets (seekable)
    head.extend_from_slice(uuid(h1, h2).as_bytes());
    // File-level metadata.
    let mut file_meta = BTreeMap::new();
    file_meta.insert("creator", Meta::String("eikon".into()));
    put_meta(&mut head, &file_meta);
    put_u32(&mut head, grids.len() as u32);
    w.write_all(&head)?;

    let mut pos = head.len() as u64;
    let mut report = WriteReport {
        bytes: 0,
        grids: Vec::with_capacity(grids.len()),
    };
    for (g, (body, block_offset, counts)) in grids.iter().zip(&bodies) {
        let mut desc = Vec::new();
        put_string(&mut desc, &g.name);
        let grid_type = stored_type(g);
        put_string(&mut desc, &grid_type);
        put_string(&mut desc, ""); // instance parent: none
        let grid_pos = pos + desc.len() as u64 + 24;
        let block_pos = grid_pos + block_offset;
        let end_pos = grid_pos + body.len() as u64;
        for p in [grid_pos, block_pos, end_pos] {
            desc.extend_from_slice(&(p as i64).to_le_bytes());
        }
        w.write_all(&desc)?;
        w.write_all(body)?;
        report.grids.push(GridReport {
            name: g.name.clone(),
            grid_type,
            active_voxels: counts.active,
            leaves: counts.leaves,
            tiles: counts.tiles,
            bytes: desc.len() as u64 + body.len() as u64,
        });
        pos = end_pos;
    }
    report.bytes = pos;
    Ok(report)
}

/// [`write`](fn@write) to the file `path`, atomically: the bytes go to a temporary
/// file beside it, which is renamed into place only once complete, so a
/// failure never leaves a partial file.
pub fn write_file(path: &Path, grids: &[Grid], options: &WriteOptions) -> Result<WriteReport> {
    let io = |source| VdbError::Io {
        path: path.to_path_buf(),
        source,
    };
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let name = path.file_name().ok_or_else(|| {
        io(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "not a file path",
        ))
    })?;
    let tmp = dir.join(format!(
        ".{}.{}.tmp",
        name.to_string_lossy(),
        std::process::id()
    ));
    let result = (|| {
        let mut w = std::io::BufWriter::new(std::fs::File::create(&tmp).map_err(io)?);
        let report = write(&mut w, grids, options)?;
        let file = w.into_inner().map_err(|e| io(e.into_error()))?;
        file.sync_all().map_err(io)?;
        std::fs::rename(&tmp, path).map_err(io)?;
        Ok(report)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// The grid type as stored in the descriptor.
fn stored_type(g: &Grid) -> String {
    let mut t = g.tree_type();
    if g.half {
        t.push_str("_HalfFloat");
    }
    t
}

/// A UUID-shaped tag (`8-4-4-4-12` upper-case hex digits).
fn uuid(a: u64, b: u64) -> String {
    let hex = format!("{a:016X}{b:016X}");
    format!(
        "{}-{}-{}-{}-{}",
        &hex[0..8],
        &hex[8..12],
        &hex[12..16],
        &hex[16..20],
        &hex[20..32]
    )
}

fn put_u32(out: &mut Vec<u8>, v: u32) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put_i32(out: &mut Vec<u8>, v: i32) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put_f64(out: &mut Vec<u8>, v: f64) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put_string(out: &mut Vec<u8>, s: &str) {
    put_u32(out, s.len() as u32);
    out.extend_from_slice(s.as_bytes());
}

fn put_words(out: &mut Vec<u8>, words: &[u64]) {
    for w in words {
        out.extend_from_slice(&w.to_le_bytes());
    }
}

/// A metadata value (`TypedMetadata<T>`).
enum Meta {
    String(String),
    Bool(bool),
    I64(i64),
    Vec3i([i32; 3]),
}

/// `MetaMap::writeMeta`: count, then name, type name, byte size and value
/// of each entry, in name order (OpenVDB's `std::map`).
fn put_meta(out: &mut Vec<u8>, meta: &BTreeMap<&str, Meta>) {
    put_u32(out, meta.len() as u32);
    for (name, value) in meta {
        put_string(out, name);
        match value {
            Meta::String(s) => {
                put_string(out, "string");
                put_string(out, s);
            }
            Meta::Bool(b) => {
                put_string(out, "bool");
                put_u32(out, 1);
                out.push(*b as u8);
            }
            Meta::I64(v) => {
                put_string(out, "int64");
                put_u32(out, 8);
                out.extend_from_slice(&v.to_le_bytes());
            }
            Meta::Vec3i(v) => {
                put_string(out, "vec3i");
                put_u32(out, 12);
                for c in v {
                    put_i32(out, *c);
                }
            }
        }
    }
}

/// Leaves, tiles and active voxels of an encoded tree.
#[derive(Clone, Copy, Debug, Default)]
struct Counts {
    active: u64,
    leaves: u64,
    tiles: u64,
}

/// One grid from its compression flags to its last leaf buffer, and the
/// offset of the leaf buffers in it (`block_pos - grid_pos`).
fn encode_grid(g: &Grid, options: &WriteOptions) -> (Vec<u8>, u64, Counts) {
    let compression = COMPRESS_ACTIVE_MASK | if options.zip { COMPRESS_ZIP } else { 0 };
    let mut out = Vec::new();
    put_u32(&mut out, compression);

    let (active, bbox) = match &g.data {
        GridData::Float(t) => (t.active_voxel_count(), t.bbox()),
        GridData::Vec3(t, _) => (t.active_voxel_count(), t.bbox()),
    };
    let mut meta = BTreeMap::new();
    meta.insert("class", Meta::String(g.class.as_str().into()));
    meta.insert("creator", Meta::String("eikon".into()));
    meta.insert("name", Meta::String(g.name.clone()));
    meta.insert("is_local_space", Meta::Bool(false));
    meta.insert("is_saved_as_half_float", Meta::Bool(g.half));
    // An empty grid's bounding box is OpenVDB's empty CoordBBox.
    let (lo, hi) = bbox.unwrap_or(([i32::MAX; 3], [i32::MIN; 3]));
    meta.insert("file_bbox_min", Meta::Vec3i(lo));
    meta.insert("file_bbox_max", Meta::Vec3i(hi));
    meta.insert("file_voxel_count", Meta::I64(active as i64));
    meta.insert(
        "file_compression",
        Meta::String(
            if options.zip {
                "zip + active values"
            } else {
                "active values"
            }
            .into(),
        ),
    );
    if let GridData::Vec3(_, vt) = &g.data {
        meta.insert("vector_type", Meta::String(vt.as_str().into()));
    }
    // file_mem_bytes: a rough in-memory size (leaf buffers and masks).
    let value_size = match &g.data {
        GridData::Float(_) => 4,
        GridData::Vec3(..) => 12,
    };
    let leaves = match &g.data {
        GridData::Float(t) => t.leaf_count(),
        GridData::Vec3(t, _) => t.leaf_count(),
    } as i64;
    meta.insert(
        "file_mem_bytes",
        Meta::I64(leaves * (LEAF_SIZE as i64 * value_size + 96)),
    );
    put_meta(&mut out, &meta);

    // Transform (`Transform::write`: map type name, then the map).
    let t = &g.transform;
    put_string(
        &mut out,
        if t.is_uniform() {
            "UniformScaleTranslateMap"
        } else {
            "ScaleTranslateMap"
        },
    );
    let inv = 1.0 / t.voxel_size;
    for v in [
        t.translation,
        t.voxel_size,
        t.voxel_size.abs(),
        inv,
        inv * inv,
        inv / 2.0,
    ] {
        put_f64(&mut out, v.x);
        put_f64(&mut out, v.y);
        put_f64(&mut out, v.z);
    }

    let mut buffers = Vec::new();
    let counts = match &g.data {
        GridData::Float(tree) => encode_tree(tree, g.half, options.zip, &mut out, &mut buffers),
        GridData::Vec3(tree, _) => encode_tree(tree, g.half, options.zip, &mut out, &mut buffers),
    };
    let block_offset = out.len() as u64;
    out.extend_from_slice(&buffers);
    (out, block_offset, counts)
}

/// An entry of a 16^3 node.
enum Entry4<'a, T> {
    Tile(T),
    Leaf(&'a Leaf<T>),
}

/// Leaves and tiles grouped under their 32^3 node (by origin) and 16^3
/// node (by child index).
type Nodes<'a, T> = BTreeMap<[i32; 3], BTreeMap<usize, BTreeMap<usize, Entry4<'a, T>>>>;

/// An entry of a 32^3 node.
enum Entry5<'a, T> {
    Tile(T),
    Node(BTreeMap<usize, Entry4<'a, T>>),
}

/// Child index of the 16^3 node (or 8^3 leaf) at `o` in its 16^3 parent.
fn offset4(o: [i32; 3]) -> usize {
    ((((o[0] & 127) >> 3) << 8) | (((o[1] & 127) >> 3) << 4) | ((o[2] & 127) >> 3)) as usize
}

/// Child index of the 16^3 node at `o` in its 32^3 parent.
fn offset5(o: [i32; 3]) -> usize {
    ((((o[0] & 4095) >> 7) << 10) | (((o[1] & 4095) >> 7) << 5) | ((o[2] & 4095) >> 7)) as usize
}

/// Tree topology (`Tree::writeTopology`) to `topo` and leaf buffers
/// (`Tree::writeBuffers`) to `bufs`.
fn encode_tree<T: VdbValue>(
    tree: &Tree<T>,
    half: bool,
    zip: bool,
    topo: &mut Vec<u8>,
    bufs: &mut Vec<u8>,
) -> Counts {
    let mut counts = Counts::default();
    // Group leaves under their 16^3 and 32^3 nodes; keys in child-index
    // order, which is the order OpenVDB writes children in.
    let mut nodes: Nodes<T> = BTreeMap::new();
    for (origin, leaf) in &tree.leaves {
        counts.active += leaf.active_count() as u64;
        if leaf.active_count() == 0 {
            continue;
        }
        let entry = match leaf.uniform_value() {
            Some(v) => Entry4::Tile(v),
            None => Entry4::Leaf(leaf),
        };
        nodes
            .entry(origin.map(|c| c & !4095))
            .or_default()
            .entry(offset5(*origin))
            .or_default()
            .insert(offset4(*origin), entry);
    }
    // A 16^3 node of 4096 equal active tiles is one tile of its parent.
    let nodes: BTreeMap<[i32; 3], BTreeMap<usize, Entry5<T>>> = nodes
        .into_iter()
        .map(|(o5, children)| {
            let children = children
                .into_iter()
                .map(|(i5, entries)| {
                    let first = match entries.values().next() {
                        Some(Entry4::Tile(v)) => Some(*v),
                        _ => None,
                    };
                    match first {
                        Some(v)
                            if entries.len() == 4096
                                && entries
                                    .values()
                                    .all(|e| matches!(e, Entry4::Tile(x) if *x == v)) =>
                        {
                            (i5, Entry5::Tile(v))
                        }
                        _ => (i5, Entry5::Node(entries)),
                    }
                })
                .collect();
            (o5, children)
        })
        .collect();

    put_u32(topo, 1); // buffer count
    let bg = tree.background();
    if half {
        bg.to_half_precision().put(topo);
    } else {
        bg.put(topo);
    }
    put_u32(topo, 0); // root tiles
    put_u32(topo, nodes.len() as u32);
    for (o5, children) in &nodes {
        for c in o5 {
            put_i32(topo, *c);
        }
        let mut child_mask = [0u64; 512];
        let mut value_mask = [0u64; 512];
        let mut tiles = Vec::new();
        for (&i, e) in children {
            match e {
                Entry5::Tile(v) => {
                    value_mask[i >> 6] |= 1 << (i & 63);
                    tiles.push(*v);
                }
                Entry5::Node(_) => child_mask[i >> 6] |= 1 << (i & 63),
            }
        }
        counts.tiles += tiles.len() as u64;
        put_words(topo, &child_mask);
        put_words(topo, &value_mask);
        put_values(topo, &tiles, half, zip);
        for e in children.values() {
            let Entry5::Node(entries) = e else { continue };
            let mut child_mask = [0u64; 64];
            let mut value_mask = [0u64; 64];
            let mut tiles = Vec::new();
            for (&i, e) in entries {
                match e {
                    Entry4::Tile(v) => {
                        value_mask[i >> 6] |= 1 << (i & 63);
                        tiles.push(*v);
                    }
                    Entry4::Leaf(_) => child_mask[i >> 6] |= 1 << (i & 63),
                }
            }
            counts.tiles += tiles.len() as u64;
            put_words(topo, &child_mask);
            put_words(topo, &value_mask);
            put_values(topo, &tiles, half, zip);
            for e in entries.values() {
                if let Entry4::Leaf(leaf) = e {
                    put_words(topo, &leaf.mask);
                }
            }
        }
    }

    // Leaf buffers, depth first in the same order: mask, then values.
    let leaves: Vec<&Leaf<T>> = nodes
        .values()
        .flat_map(|c| c.values())
        .filter_map(|e| match e {
            Entry5::Node(entries) => Some(entries.values()),
            Entry5::Tile(_) => None,
        })
        .flatten()
        .filter_map(|e| match e {
            Entry4::Leaf(l) => Some(*l),
            Entry4::Tile(_) => None,
        })
        .collect();
    counts.leaves = leaves.len() as u64;
    let encoded: Vec<Vec<u8>> = leaves
        .par_iter()
        .map(|leaf| {
            let mut out = Vec::with_capacity(64 + LEAF_SIZE * 12 + 9);
            put_words(&mut out, &leaf.mask);
            let active: Vec<T> = (0..LEAF_SIZE)
                .filter(|&n| leaf.mask[n >> 6] >> (n & 63) & 1 == 1)
                .map(|n| leaf.values[n])
                .collect();
            put_values(&mut out, &active, half, zip);
            out
        })
        .collect();
    for e in encoded {
        bufs.extend_from_slice(&e);
    }
    counts
}

/// `io::writeCompressedValues` with `COMPRESS_ACTIVE_MASK` for a node whose
/// inactive values are all the background: the metadata byte, then the
/// active values only, as half floats or floats, zipped or raw.
fn put_values<T: VdbValue>(out: &mut Vec<u8>, active: &[T], half: bool, zip: bool) {
    out.push(NO_MASK_OR_INACTIVE_VALS);
    let mut raw = Vec::with_capacity(active.len() * 12);
    if half {
        // OpenVDB's HalfWriter writes nothing at all for zero values.
        if active.is_empty() {
            return;
        }
        for v in active {
            v.put_half(&mut raw);
        }
    } else {
        for v in active {
            v.put(&mut raw);
        }
    }
    if zip {
        zip_to(out, &raw);
    } else {
        out.extend_from_slice(&raw);
    }
}

/// `io::zipToStream`: the zlib stream with its byte count, or, when that
/// would not be smaller, the raw bytes with their count negated.
fn zip_to(out: &mut Vec<u8>, raw: &[u8]) {
    let mut enc = flate2::write::ZlibEncoder::new(
        Vec::with_capacity(raw.len() / 2 + 16),
        flate2::Compression::fast(),
    );
    let zipped = enc
        .write_all(raw)
        .and_then(|_| enc.finish())
        .expect("compressing into memory cannot fail");
    if zipped.len() < raw.len() {
        out.extend_from_slice(&(zipped.len() as i64).to_le_bytes());
        out.extend_from_slice(&zipped);
    } else {
        out.extend_from_slice(&(-(raw.len() as i64)).to_le_bytes());
        out.extend_from_slice(raw);
    }
}
