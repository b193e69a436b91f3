//! Reading float grids: our own structural check of the whole file, then
//! the values through vdb-rs.
//!
//! vdb-rs 0.6 decodes OpenVDB's values (raw, zip, blosc, half floats) but
//! trusts its input: it reads any grid type as if it were the requested one
//! (a vec3s grid comes back empty or garbled), drops root-level tiles,
//! panics on transforms other than (uniform) scale-translate maps, on
//! duplicate grid names and on several malformed inputs, and misreads half
//! floats stored with compression. [`inspect`] walks every byte vdb-rs will
//! read and refuses those cases with an error that names the file, the grid
//! and the problem; only then does vdb-rs see the file, and its result is
//! checked against the active-voxel count found here.

use super::write::{COMPRESS_ACTIVE_MASK, COMPRESS_BLOSC, COMPRESS_ZIP, MAGIC};
use super::{Result, Transform, Tree, VdbError};
use glam::DVec3;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Oldest file format read (`OPENVDB_FILE_VERSION_NODE_MASK_COMPRESSION`:
/// per-grid compression; OpenVDB 3 and later).
const MIN_VERSION: u32 = 222;
/// Newest file format read.
const MAX_VERSION: u32 = 224;
/// The float tree type.
const FLOAT_TREE: &str = "Tree_float_5_4_3";
/// Largest dense box an imported grid may span, voxels.
const MAX_DENSE: u64 = 1 << 28;
/// vdb-rs reports voxel coordinates as f32: beyond this they lose precision.
const MAX_COORD: i64 = 1 << 24;

/// A metadata value as stored in a file.
#[derive(Clone, Debug, PartialEq)]
pub enum MetaValue {
    /// `string`
    String(String),
    /// `bool`
    Bool(bool),
    /// `int32`
    I32(i32),
    /// `int64`
    I64(i64),
    /// `float`
    Float(f32),
    /// `vec3i`
    Vec3i([i32; 3]),
    /// Any other type, by its type name.
    Other(String),
}

/// One grid of a file, as its descriptor and metadata describe it.
#[derive(Clone, Debug)]
pub struct GridInfo {
    /// Grid name.
    pub name: String,
    /// Tree type without the half-float suffix, e.g. `Tree_float_5_4_3`.
    pub grid_type: String,
    /// Stored as half floats (`_HalfFloat` type suffix).
    pub half: bool,
    /// Name of the grid whose tree this one shares ("" when none).
    pub instance_parent: String,
    /// Compression flags (`io::COMPRESS_*`).
    pub compression: u32,
    /// Grid metadata.
    pub metadata: BTreeMap<String, MetaValue>,
    grid_pos: usize,
    block_pos: usize,
    end_pos: usize,
}

/// What [`inspect`] found in a file.
#[derive(Clone, Debug)]
pub struct FileInfo {
    /// File format version.
    pub file_version: u32,
    /// Library version that wrote it (major, minor).
    pub library_version: (u32, u32),
    /// File metadata.
    pub metadata: BTreeMap<String, MetaValue>,
    /// The grids, in file order.
    pub grids: Vec<GridInfo>,
}

/// Bounds-checked little-endian reads over a file's bytes.
struct Bytes<'a> {
    data: &'a [u8],
    pos: usize,
    path: &'a Path,
}

impl<'a> Bytes<'a> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8]> {
        match self.pos.checked_add(n) {
            Some(end) if end <= self.data.len() => {
                let s = &self.data[self.pos..end];
                self.pos = end;
                Ok(s)
            }
            _ => Err(VdbError::Truncated {
                path: self.path.to_path_buf(),
                what: what.to_string(),
                at: self.pos,
                len: self.data.len(),
            }),
        }
    }

    fn array<const N: usize>(&mut self, what: &str) -> Result<[u8; N]> {
        Ok(self.take(N, what)?.try_into().expect("length checked"))
    }

    fn u8(&mut self, what: &str) -> Result<u8> {
        Ok(self.take(1, what)?[0])
    }

    fn u32(&mut self, what: &str) -> Result<u32> {
        Ok(u32::from_le_bytes(self.array(what)?))
    }

    fn i32(&mut self, what: &str) -> Result<i32> {
        Ok(i32::from_le_bytes(self.array(what)?))
    }

    fn i64(&mut self, what: &str) -> Result<i64> {
        Ok(i64::from_le_bytes(self.array(what)?))
    }

    fn f32(&mut self, what: &str) -> Result<f32> {
        Ok(f32::from_le_bytes(self.array(what)?))
    }

    fn dvec3(&mut self, what: &str) -> Result<DVec3> {
        let mut v = [0.0; 3];
        for c in &mut v {
            *c = f64::from_le_bytes(self.array(what)?);
        }
        Ok(DVec3::from_array(v))
    }

    fn coord(&mut self, what: &str) -> Result<[i32; 3]> {
        Ok([self.i32(what)?, self.i32(what)?, self.i32(what)?])
    }

    fn string(&mut self, what: &str) -> Result<String> {
        let n = self.u32(what)? as usize;
        Ok(String::from_utf8_lossy(self.take(n, what)?).into_owned())
    }

    fn words(&mut self, n: usize, what: &str) -> Result<Vec<u64>> {
        Ok(self
            .take(8 * n, what)?
            .chunks_exact(8)
            .map(|c| u64::from_le_bytes(c.try_into().expect("8 bytes")))
            .collect())
    }

    fn corrupt(&self, message: impl Into<String>) -> VdbError {
        VdbError::Corrupt {
            path: self.path.to_path_buf(),
            message: message.into(),
        }
    }
}

/// The largest VDB file read.
pub const MAX_VDB_BYTES: u64 = 16 << 30;

fn read_file(path: &Path) -> Result<Vec<u8>> {
    eikon_mesh::load::read_file(path, MAX_VDB_BYTES).map_err(|source| VdbError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Read a file's header, metadata and grid descriptors (not the trees).
pub fn inspect(path: &Path) -> Result<FileInfo> {
    let data = read_file(path)?;
    parse_header(&data, path)
}

/// `MetaMap::readMeta`, with the sizes vdb-rs assumes for the types it knows.
fn read_meta(b: &mut Bytes, what: &str) -> Result<BTreeMap<String, MetaValue>> {
    let count = b.u32(&format!("{what} count"))?;
    let mut out = BTreeMap::new();
    for _ in 0..count {
        let name = b.string(&format!("{what} name"))?;
        let ty = b.string(&format!("{what} `{name}` type"))?;
        let len = b.u32(&format!("{what} `{name}` size"))? as usize;
        let at = format!("{what} `{name}`");
        let fixed = match ty.as_str() {
            "bool" => Some(1),
            "int32" | "float" => Some(4),
            "int64" => Some(8),
            "vec3i" => Some(12),
            _ => None,
        };
        if let Some(n) = fixed {
            if len != n {
                return Err(b.corrupt(format!(
                    "{at}: a {ty} value takes {n} bytes, the file says {len}"
                )));
            }
        }
        let raw = b.take(len, &at)?;
        let mut r = Bytes {
            data: raw,
            pos: 0,
            path: b.path,
        };
        let value = match ty.as_str() {
            "string" => MetaValue::String(String::from_utf8_lossy(raw).into_owned()),
            "bool" => MetaValue::Bool(raw[0] != 0),
            "int32" => MetaValue::I32(r.i32(&at)?),
            "int64" => MetaValue::I64(r.i64(&at)?),
            "float" => MetaValue::Float(r.f32(&at)?),
            "vec3i" => MetaValue::Vec3i(r.coord(&at)?),
            _ => MetaValue::Other(ty),
        };
        out.insert(name, value);
    }
    Ok(out)
}

fn parse_header(data: &[u8], path: &Path) -> Result<FileInfo> {
    let mut b = Bytes { data, pos: 0, path };
    let magic = b.i64("magic number")?;
    if magic != MAGIC {
        return Err(b.corrupt(format!(
            "bad magic number {magic:#x} (an OpenVDB file starts with 0x56444220)"
        )));
    }
    let file_version = b.u32("file version")?;
    let unsupported = |message: String| VdbError::Unsupported {
        path: path.to_path_buf(),
        name: String::new(),
        message,
    };
    if !(MIN_VERSION..=MAX_VERSION).contains(&file_version) {
        return Err(unsupported(format!(
            "file format version {file_version}: only versions {MIN_VERSION} to {MAX_VERSION} can be read (OpenVDB 3 and later write 222 or newer; re-save the file with a current OpenVDB)"
        )));
    }
    let library_version = (b.u32("library version")?, b.u32("library version")?);
    if b.u8("grid offsets flag")? != 1 {
        return Err(unsupported(
            "the file has no grid offsets (written as a stream): re-save it as a file".into(),
        ));
    }
    b.take(36, "unique tag (UUID)")?;
    let metadata = read_meta(&mut b, "file metadata")?;
    let count = b.i32("grid count")?;
    if count < 0 {
        return Err(b.corrupt(format!("negative grid count {count}")));
    }
    let mut grids: Vec<GridInfo> = Vec::new();
    for g in 0..count {
        let what = |s: &str| format!("grid descriptor {g}: {s}");
        let name = b.string(&what("name"))?;
        let mut grid_type = b.string(&what("type"))?;
        let half = grid_type.ends_with("_HalfFloat");
        if half {
            grid_type.truncate(grid_type.len() - "_HalfFloat".len());
        }
        let instance_parent = b.string(&what("instance parent"))?;
        let mut pos = [0usize; 3];
        for p in &mut pos {
            let v = b.i64(&what("offsets"))?;
            *p = usize::try_from(v).map_err(|_| b.corrupt(what("negative offset")))?;
        }
        let [grid_pos, block_pos, end_pos] = pos;
        if !(b.pos <= grid_pos && grid_pos <= block_pos && block_pos <= end_pos) {
            return Err(b.corrupt(format!(
                "grid `{name}`: offsets {grid_pos}, {block_pos}, {end_pos} are out of order"
            )));
        }
        if end_pos > data.len() {
            return Err(VdbError::Truncated {
                path: path.to_path_buf(),
                what: format!("grid `{name}` (ends at byte {end_pos})"),
                at: grid_pos,
                len: data.len(),
            });
        }
        if grids.iter().any(|x| x.name == name) {
            return Err(b.corrupt(format!("two grids are named `{name}`")));
        }
        b.pos = grid_pos;
        let compression = b.u32(&format!("grid `{name}` compression"))?;
        if compression & !(COMPRESS_ZIP | COMPRESS_ACTIVE_MASK | COMPRESS_BLOSC) != 0 {
            return Err(b.corrupt(format!(
                "grid `{name}`: unknown compression flags {compression:#x}"
            )));
        }
        let metadata = read_meta(&mut b, &format!("grid `{name}` metadata"))?;
        if b.pos > block_pos {
            return Err(b.corrupt(format!(
                "grid `{name}`: metadata runs past the grid's data blocks"
            )));
        }
        grids.push(GridInfo {
            name,
            grid_type,
            half,
            instance_parent,
            compression,
            metadata,
            grid_pos,
            block_pos,
            end_pos,
        });
        b.pos = end_pos;
    }
    Ok(FileInfo {
        file_version,
        library_version,
        metadata,
        grids,
    })
}

/// The active content of a float tree found by the structural check.
struct TreeCheck {
    transform: Transform,
    background: f32,
    active: u64,
    bbox: Option<([i32; 3], [i32; 3])>,
}

fn grow(bbox: &mut Option<([i32; 3], [i32; 3])>, lo: [i32; 3], size: i32) {
    let hi = lo.map(|c| c + size - 1);
    let b = bbox.get_or_insert((lo, hi));
    for a in 0..3 {
        b.0[a] = b.0[a].min(lo[a]);
        b.1[a] = b.1[a].max(hi[a]);
    }
}

/// Positions of the set bits of a mask, in order.
fn set_bits(words: &[u64]) -> impl Iterator<Item = usize> + '_ {
    words.iter().enumerate().flat_map(|(w, &word)| {
        let mut rest = word;
        std::iter::from_fn(move || {
            (rest != 0).then(|| {
                let b = rest.trailing_zeros() as usize;
                rest &= rest - 1;
                64 * w + b
            })
        })
    })
}

fn ones(words: &[u64]) -> u64 {
    words.iter().map(|w| w.count_ones() as u64).sum()
}

/// Local coordinates of child `n` of a node with `log2` children per axis.
fn local(n: usize, log2: u32) -> [i32; 3] {
    let m = (1 << log2) - 1;
    [
        (n >> (2 * log2)) as i32,
        ((n >> log2) & m) as i32,
        (n & m) as i32,
    ]
}

/// `io::readCompressedValues` of `num` float values without keeping them:
/// checks the sizes vdb-rs will rely on.
fn skip_values(
    b: &mut Bytes,
    info: &GridInfo,
    num: usize,
    value_mask: &[u64],
    what: &str,
) -> Result<()> {
    let meta = b.u8(&format!("{what}: value metadata"))?;
    if meta > 6 {
        return Err(b.corrupt(format!("{what}: unknown value metadata {meta}")));
    }
    if matches!(meta, 2 | 4 | 5) {
        b.take(4, &format!("{what}: inactive value"))?;
    }
    if meta == 5 {
        b.take(4, &format!("{what}: inactive value"))?;
    }
    if matches!(meta, 3..=5) {
        b.take(num / 8, &format!("{what}: selection mask"))?;
    }
    let count = if info.compression & COMPRESS_ACTIVE_MASK != 0 && meta != 6 {
        ones(value_mask) as usize
    } else {
        num
    };
    let bytes = count * if info.half { 2 } else { 4 };
    if info.half && count == 0 {
        return Ok(()); // OpenVDB writes nothing at all
    }
    if info.compression & (COMPRESS_BLOSC | COMPRESS_ZIP) != 0 {
        let n = b.i64(&format!("{what}: compressed size"))?;
        if n <= 0 {
            if n.unsigned_abs() != bytes as u64 {
                return Err(b.corrupt(format!(
                    "{what}: {} uncompressed bytes stored where {bytes} are expected",
                    n.unsigned_abs()
                )));
            }
            b.take(bytes, &format!("{what}: values"))?;
        } else {
            let n = usize::try_from(n).map_err(|_| b.corrupt(format!("{what}: huge size")))?;
            let chunk = b.take(n, &format!("{what}: compressed values"))?;
            if info.compression & COMPRESS_BLOSC != 0 && count > 0 {
                // Blosc header: version, versionlz, flags, typesize, nbytes,
                // blocksize, cbytes (u32 each from byte 4).
                let field = |i: usize| {
                    chunk
                        .get(i..i + 4)
                        .map(|s| u32::from_le_bytes(s.try_into().expect("4 bytes")) as usize)
                };
                match (field(4), field(12)) {
                    (Some(nbytes), Some(cbytes)) if nbytes == bytes && cbytes <= n => {}
                    _ => {
                        return Err(b.corrupt(format!(
                            "{what}: blosc block does not hold the {bytes} bytes expected"
                        )))
                    }
                }
            }
        }
    } else {
        b.take(bytes, &format!("{what}: values"))?;
    }
    Ok(())
}

/// Walk the whole tree of float grid `info` (transform, topology, buffers)
/// as vdb-rs will, refusing what vdb-rs cannot read.
fn check_tree(data: &[u8], path: &Path, info: &GridInfo) -> Result<TreeCheck> {
    let name = &info.name;
    let unsupported = |message: String| VdbError::Unsupported {
        path: path.to_path_buf(),
        name: name.clone(),
        message,
    };
    let meta_half = info.metadata.get("is_saved_as_half_float") == Some(&MetaValue::Bool(true));
    if meta_half != info.half {
        return Err(unsupported(format!(
            "the type name says {} floats but the metadata is_saved_as_half_float says {}",
            if info.half { "half" } else { "full" },
            if meta_half { "half" } else { "full" }
        )));
    }
    if info.half && info.compression & (COMPRESS_ZIP | COMPRESS_BLOSC) != 0 {
        return Err(unsupported(
            "half-float values with zip or blosc compression cannot be read by vdb-rs; save the grid uncompressed (`eikon export --uncompressed`) or as full floats".into(),
        ));
    }
    let mut b = Bytes {
        data,
        pos: info.grid_pos,
        path,
    };
    b.u32("compression")?;
    read_meta(&mut b, "grid metadata")?;
    let map = b.string(&format!("grid `{name}` transform"))?;
    let transform = match map.as_str() {
        "UniformScaleTranslateMap" | "ScaleTranslateMap" => {
            let translation = b.dvec3("transform")?;
            let scale = b.dvec3("transform")?;
            for _ in 0..4 {
                b.dvec3("transform")?;
            }
            Transform {
                voxel_size: scale,
                translation,
            }
        }
        "UniformScaleMap" => {
            let scale = b.dvec3("transform")?;
            for _ in 0..4 {
                b.dvec3("transform")?;
            }
            Transform {
                voxel_size: scale,
                translation: DVec3::ZERO,
            }
        }
        other => {
            return Err(unsupported(format!(
                "transform `{other}` is not supported (only UniformScaleMap, UniformScaleTranslateMap and ScaleTranslateMap: no rotation, shear or frustum)"
            )))
        }
    };
    if !(transform.voxel_size.is_finite()
        && transform.translation.is_finite()
        && transform.voxel_size.abs().min_element() > 0.0)
    {
        return Err(b.corrupt(format!(
            "grid `{name}`: degenerate transform (voxel size {}, translation {})",
            transform.voxel_size, transform.translation
        )));
    }
    let buffers = b.u32("buffer count")?;
    if buffers != 1 {
        return Err(unsupported(format!(
            "{buffers} buffers per leaf (multi-buffer trees) are not supported"
        )));
    }
    let background = b.f32("background")?;
    let tiles = b.u32("root tile count")?;
    let children = b.u32("root child count")?;
    for _ in 0..tiles {
        let at = b.coord("root tile")?;
        let value = b.f32("root tile")?;
        let active = b.u8("root tile")?;
        if active != 0 || value != background {
            return Err(unsupported(format!(
                "root-level tile at {at:?} (value {value}, {}): vdb-rs drops root tiles; voxelize the tile or re-save the grid after `tools::prune` with a smaller tile",
                if active != 0 { "active" } else { "inactive" }
            )));
        }
    }
    let mut active = 0u64;
    let mut bbox = None;
    let mut leaves: Vec<Vec<u64>> = Vec::new();
    for r in 0..children {
        let o5 = b.coord("root child origin")?;
        if o5.iter().any(|c| c & 4095 != 0) {
            return Err(b.corrupt(format!(
                "root child {r}: origin {o5:?} is not a multiple of 4096"
            )));
        }
        if o5.iter().any(|&c| (c as i64).abs() >= MAX_COORD) {
            return Err(unsupported(format!(
                "voxels at {o5:?} lie beyond +-{MAX_COORD} (vdb-rs gives coordinates as 32-bit floats)"
            )));
        }
        let what5 = format!("32^3 node at {o5:?}");
        let child5 = b.words(512, &what5)?;
        let value5 = b.words(512, &what5)?;
        if child5.iter().zip(&value5).any(|(c, v)| c & v != 0) {
            return Err(b.corrupt(format!("{what5}: an entry is both a child and a tile")));
        }
        skip_values(&mut b, info, 32768, &value5, &what5)?;
        for n in set_bits(&value5) {
            let l = local(n, 5);
            grow(&mut bbox, [0, 1, 2].map(|a| o5[a] + 128 * l[a]), 128);
            active += 128 * 128 * 128;
        }
        for n5 in set_bits(&child5) {
            let l = local(n5, 5);
            let o4 = [0, 1, 2].map(|a| o5[a] + 128 * l[a]);
            let what4 = format!("16^3 node at {o4:?}");
            let child4 = b.words(64, &what4)?;
            let value4 = b.words(64, &what4)?;
            if child4.iter().zip(&value4).any(|(c, v)| c & v != 0) {
                return Err(b.corrupt(format!("{what4}: an entry is both a child and a tile")));
            }
            skip_values(&mut b, info, 4096, &value4, &what4)?;
            for n in set_bits(&value4) {
                let l = local(n, 4);
                grow(&mut bbox, [0, 1, 2].map(|a| o4[a] + 8 * l[a]), 8);
                active += 512;
            }
            for n4 in set_bits(&child4) {
                let l = local(n4, 4);
                let o3 = [0, 1, 2].map(|a| o4[a] + 8 * l[a]);
                let mask = b.words(8, &format!("leaf at {o3:?}"))?;
                for n in set_bits(&mask) {
                    let l = local(n, 3);
                    grow(&mut bbox, [0, 1, 2].map(|a| o3[a] + l[a]), 1);
                }
                active += ones(&mask);
                leaves.push(mask);
            }
        }
    }
    if b.pos != info.block_pos {
        return Err(b.corrupt(format!(
            "grid `{name}`: the tree topology ends at byte {} but the leaf data should start at {}",
            b.pos, info.block_pos
        )));
    }
    for (i, mask) in leaves.iter().enumerate() {
        let what = format!("grid `{name}` leaf buffer {i}");
        let m = b.words(8, &what)?;
        if &m != mask {
            return Err(b.corrupt(format!("{what}: value mask differs from the topology")));
        }
        skip_values(&mut b, info, 512, mask, &what)?;
    }
    if b.pos != info.end_pos {
        return Err(b.corrupt(format!(
            "grid `{name}`: the leaf data ends at byte {} but the grid should end at {}",
            b.pos, info.end_pos
        )));
    }
    Ok(TreeCheck {
        transform,
        background,
        active,
        bbox,
    })
}

/// A float grid read from a file, held densely over its active bounding box
/// (plus one voxel of background all round) for sampling.
#[derive(Clone)]
pub struct FloatVolume {
    /// The file it came from.
    pub path: PathBuf,
    /// Grid name.
    pub name: String,
    /// Index-to-world map (voxel centres at whole index coordinates).
    pub transform: Transform,
    /// Value of inactive voxels and of everything outside the grid.
    pub background: f32,
    /// Stored as half floats.
    pub half: bool,
    /// Active voxels in the file (tiles counted voxel by voxel).
    pub active_voxels: u64,
    /// Index coordinate of `values[0]`.
    origin: [i32; 3],
    /// Size of the dense box.
    dims: [usize; 3],
    /// x slowest, z fastest.
    values: Vec<f32>,
}

impl std::fmt::Debug for FloatVolume {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FloatVolume")
            .field("path", &self.path)
            .field("name", &self.name)
            .field("transform", &self.transform)
            .field("background", &self.background)
            .field("active_voxels", &self.active_voxels)
            .field("origin", &self.origin)
            .field("dims", &self.dims)
            .finish_non_exhaustive()
    }
}

impl FloatVolume {
    /// Index coordinate of the first voxel of the dense box.
    pub fn origin(&self) -> [i32; 3] {
        self.origin
    }

    /// Size of the dense box, voxels.
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    fn flat(&self, l: [usize; 3]) -> usize {
        (l[0] * self.dims[1] + l[1]) * self.dims[2] + l[2]
    }

    /// Position of `ijk` in the dense box, if inside.
    fn local(&self, ijk: [i32; 3]) -> Option<[usize; 3]> {
        let mut l = [0usize; 3];
        for a in 0..3 {
            let d = ijk[a] as i64 - self.origin[a] as i64;
            if d < 0 || d >= self.dims[a] as i64 {
                return None;
            }
            l[a] = d as usize;
        }
        Some(l)
    }

    /// The value of voxel `ijk` (the background where inactive).
    pub fn value(&self, ijk: [i32; 3]) -> f32 {
        match self.local(ijk) {
            Some(l) => self.values[self.flat(l)],
            None => self.background,
        }
    }

    /// Trilinear interpolation at world point `p` between voxel centres
    /// (OpenVDB's `BoxSampler`); the background far from the data.
    pub fn sample(&self, p: DVec3) -> f64 {
        let u = self.transform.world_to_index(p);
        if !u.is_finite() {
            return self.background as f64;
        }
        let f = u.floor();
        let t = u - f;
        let base = [f.x, f.y, f.z];
        // Entirely outside the box (with a voxel to spare): background.
        for (a, &b) in base.iter().enumerate() {
            let lo = self.origin[a] as f64 - 1.0;
            let hi = self.origin[a] as f64 + self.dims[a] as f64;
            if b < lo || b > hi {
                return self.background as f64;
            }
        }
        let i0 = base.map(|c| c as i32);
        let mut out = 0.0;
        for corner in 0..8 {
            let d = [corner & 1, (corner >> 1) & 1, (corner >> 2) & 1];
            let mut w = 1.0;
            for a in 0..3 {
                w *= if d[a] == 1 { t[a] } else { 1.0 - t[a] };
            }
            if w != 0.0 {
                out += w * self.value([i0[0] + d[0], i0[1] + d[1], i0[2] + d[2]]) as f64;
            }
        }
        out
    }

    /// Whether every value (background included) is finite.
    pub fn is_finite(&self) -> bool {
        self.background.is_finite() && self.values.iter().all(|v| v.is_finite())
    }

    /// Smallest and largest value anywhere (background included).
    pub fn range(&self) -> (f32, f32) {
        self.values
            .iter()
            .fold((self.background, self.background), |(lo, hi), &v| {
                (lo.min(v), hi.max(v))
            })
    }

    /// Every voxel of the dense box with its index coordinate.
    pub(crate) fn voxels(&self) -> impl Iterator<Item = ([i32; 3], f32)> + '_ {
        let [_, ny, nz] = self.dims;
        self.values.iter().enumerate().map(move |(n, &v)| {
            let l = [n / (ny * nz), (n / nz) % ny, n % nz];
            ([0, 1, 2].map(|a| self.origin[a] + l[a] as i32), v)
        })
    }
}

/// A float grid read from a file, sparse: every active voxel (tiles
/// expanded voxel by voxel).
#[derive(Clone, Debug)]
pub struct FloatGrid {
    /// The file it came from.
    pub path: PathBuf,
    /// Grid name.
    pub name: String,
    /// Index-to-world map (voxel centres at whole index coordinates).
    pub transform: Transform,
    /// Stored as half floats.
    pub half: bool,
    /// The active voxels and the background.
    pub tree: Tree<f32>,
}

/// Read float grid `name` of the OpenVDB file at `path`: the structural
/// check of the whole file, the values through vdb-rs, and a check that
/// vdb-rs returned every active voxel.
pub fn read_float_tree(path: &Path, name: &str) -> Result<FloatGrid> {
    let data = read_file(path)?;
    let file = parse_header(&data, path)?;
    let Some(info) = file.grids.iter().find(|g| g.name == name) else {
        return Err(VdbError::NoSuchGrid {
            path: path.to_path_buf(),
            name: name.to_string(),
            available: file.grids.iter().map(|g| g.name.clone()).collect(),
        });
    };
    if info.grid_type != FLOAT_TREE {
        return Err(VdbError::WrongType {
            path: path.to_path_buf(),
            name: name.to_string(),
            grid_type: match info.grid_type.strip_prefix("Tree_") {
                Some(t) => t.trim_end_matches("_5_4_3").to_string(),
                None => info.grid_type.clone(),
            },
        });
    }
    let unsupported = |message: String| VdbError::Unsupported {
        path: path.to_path_buf(),
        name: name.to_string(),
        message,
    };
    if !info.instance_parent.is_empty() {
        return Err(unsupported(format!(
            "an instance of grid `{}` (shared trees are not supported; import `{}` itself)",
            info.instance_parent, info.instance_parent
        )));
    }
    let check = check_tree(&data, path, info)?;

    // The values, through vdb-rs (behind a guard: a panic there is a bug
    // the check above missed, reported as an error rather than a crash).
    let read = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        let mut reader = vdb_rs::VdbReader::new(std::io::Cursor::new(&data[..]))?;
        let grid = reader.read_grid::<f32>(name)?;
        let mut items: Vec<([i32; 3], f32, i32)> = Vec::new();
        for (c, v, level) in grid.iter() {
            let size = match level {
                vdb_rs::VdbLevel::Voxel => 1,
                vdb_rs::VdbLevel::Node3 => 8,
                vdb_rs::VdbLevel::Node4 => 128,
            };
            items.push(([c.x as i32, c.y as i32, c.z as i32], v, size));
        }
        Ok::<_, vdb_rs::ParseError>(items)
    }));
    let items = match read {
        Ok(Ok(items)) => items,
        Ok(Err(e)) => {
            return Err(VdbError::Corrupt {
                path: path.to_path_buf(),
                message: format!("grid `{name}`: vdb-rs: {e}"),
            })
        }
        Err(_) => {
            return Err(unsupported(
                "vdb-rs failed on this grid (it panicked); the file may use a feature it does not handle".into(),
            ))
        }
    };
    let mut tree = Tree::new(check.background);
    for (c, v, size) in items {
        if size == 1 {
            tree.set(c, v);
        } else if c.iter().all(|x| x % 8 == 0) {
            tree.fill_tile(c, size, v);
        } else {
            return Err(unsupported(format!(
                "vdb-rs returned a misaligned tile at {c:?}"
            )));
        }
    }
    let seen = tree.active_voxel_count();
    if seen != check.active || tree.bbox() != check.bbox {
        return Err(unsupported(format!(
            "vdb-rs returned {seen} active voxels in {:?} but the file holds {} in {:?}",
            tree.bbox(),
            check.active,
            check.bbox
        )));
    }
    Ok(FloatGrid {
        path: path.to_path_buf(),
        name: name.to_string(),
        transform: check.transform,
        half: info.half,
        tree,
    })
}

/// Read float grid `name` (as [`read_float_tree`]) into a dense box over
/// its active voxels, for sampling.
pub fn read_float_grid(path: &Path, name: &str) -> Result<FloatVolume> {
    FloatVolume::from_grid(read_float_tree(path, name)?)
}

impl FloatVolume {
    /// The dense box of a sparse grid: its active bounding box and a voxel
    /// of background all round.
    pub fn from_grid(grid: FloatGrid) -> Result<FloatVolume> {
        let tree = &grid.tree;
        let (origin, dims) = match tree.bbox() {
            Some((lo, hi)) => {
                let origin = lo.map(|c| c - 1);
                let dims = [0, 1, 2].map(|a| (hi[a] as i64 - lo[a] as i64 + 3) as u64);
                let total = dims.iter().product::<u64>();
                if total > MAX_DENSE {
                    return Err(VdbError::Unsupported {
                        path: grid.path.clone(),
                        name: grid.name.clone(),
                        message: format!(
                            "the active voxels span {} x {} x {} = {total} voxels; import is limited to {MAX_DENSE}",
                            dims[0], dims[1], dims[2]
                        ),
                    });
                }
                (origin, dims.map(|d| d as usize))
            }
            None => ([0; 3], [0; 3]),
        };
        let mut volume = FloatVolume {
            path: grid.path.clone(),
            name: grid.name.clone(),
            transform: grid.transform,
            background: tree.background(),
            half: grid.half,
            active_voxels: tree.active_voxel_count(),
            origin,
            dims,
            values: vec![tree.background(); dims.iter().product()],
        };
        for (ijk, v) in tree.active_voxels() {
            let l = volume.local(ijk).expect("inside the bounding box");
            let n = volume.flat(l);
            volume.values[n] = v;
        }
        Ok(volume)
    }
}
