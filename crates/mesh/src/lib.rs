//! Triangle meshes that bound refractive media.
//!
//! Walter et al. (2009) render single scattering in media whose boundary is a
//! triangle mesh with interpolated normals; Holzschuch (2015) extends that, and
//! Schmidt & Budge's nested dielectrics need every boundary closed so that a
//! ray entering a medium also leaves it. This crate holds the geometry side:
//!
//! - [`mesh`]: the [`Mesh`] (positions, per-vertex normals, triangles), the
//!   angle-weighted normals, and the watertightness check ([`CheckReport`],
//!   [`Mesh::require_closed`]).
//! - [`load`](mod@load): OBJ (via `tobj`) and PLY (via `ply-rs-bw`) reading and writing.
//! - [`procedural`]: icospheres, the papers' bumpy sphere, solids of revolution
//!   with the grid crate's profile convention, boxes.
//! - [`bvh`]: a binned-SAH bounding volume hierarchy with closest-hit and
//!   any-hit queries and the watertight ray-triangle test of Woop et al. 2013.
//!
//! Bad input never panics: it comes back as a [`MeshError`] that names the
//! file (or the procedural shape) and what is wrong.

#![warn(missing_docs)]

pub mod bvh;
pub mod load;
pub mod mesh;
pub mod polyhedron;
pub mod procedural;

pub use bvh::{Bvh, FlatNode, Hit, Ray};
pub use load::{load, load_obj, load_ply, save, write_obj, write_ply, PlyEncoding};
pub use mesh::{CheckReport, Mesh, WeldSummary};
pub use polyhedron::cuboctahedron;
pub use procedural::{
    cuboid, geodesic_sphere, icosphere, revolution, revolution_open, Bump, BumpySphere,
};

/// Everything that can go wrong when reading, building or checking a mesh.
///
/// `name` is the file path for loaded meshes (with `:line` appended where the
/// line is known) and a short description for procedural ones.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MeshError {
    /// The file could not be read (missing, a directory, no permission, ...).
    #[error("{path}: cannot read the mesh file: {source}")]
    Read {
        /// The file.
        path: String,
        /// Why the operating system refused.
        #[source]
        source: std::io::Error,
    },
    /// The file could not be written.
    #[error("{path}: cannot write the mesh file: {source}")]
    Write {
        /// The file.
        path: String,
        /// Why the operating system refused.
        #[source]
        source: std::io::Error,
    },
    /// The extension names no format we read or write.
    #[error("{path}: unknown mesh format {extension:?}; expected .obj or .ply")]
    UnknownExtension {
        /// The file.
        path: String,
        /// Its extension (empty when it has none).
        extension: String,
    },
    /// The file has zero bytes.
    #[error("{name}: the file is empty")]
    EmptyFile {
        /// The file.
        name: String,
    },
    /// The mesh has no triangles (a point cloud, or faces all dropped).
    #[error("{name}: the mesh has no triangles{detail}")]
    NoTriangles {
        /// The file or shape.
        name: String,
        /// Extra context, starting with a separator (may be empty).
        detail: String,
    },
    /// The file does not parse as its format.
    #[error("{name}: not a valid {format} file: {message}")]
    Parse {
        /// The file.
        name: String,
        /// "OBJ" or "PLY".
        format: &'static str,
        /// The parser's explanation.
        message: String,
    },
    /// A vertex coordinate is NaN or infinite.
    #[error("{name}: vertex {index} (counting from 0) is not finite: {position:?}")]
    NonFiniteVertex {
        /// The file (with line) or shape.
        name: String,
        /// The vertex.
        index: usize,
        /// Its coordinates.
        position: [f64; 3],
    },
    /// A face refers to a vertex that does not exist.
    #[error("{name}: face {face} refers to vertex {vertex}, but there are only {count} vertices")]
    IndexOutOfRange {
        /// The file or shape.
        name: String,
        /// The face (counting from 0; for a mesh, the triangle).
        face: usize,
        /// The vertex index it holds.
        vertex: u64,
        /// How many vertices there are.
        count: usize,
    },
    /// A face lists fewer than three vertices.
    #[error("{name}: face {face} has {count} vertices; a face needs at least 3")]
    ShortFace {
        /// The file.
        name: String,
        /// The face (counting from 0).
        face: usize,
        /// How many vertices it lists.
        count: usize,
    },
    /// More vertices or triangles than 32-bit indices can address.
    #[error("{name}: {count} vertices or triangles do not fit 32-bit indices")]
    TooLarge {
        /// The file or shape.
        name: String,
        /// How many there are.
        count: usize,
    },
    /// The normals do not match the vertices.
    #[error("{name}: {message}")]
    BadNormals {
        /// The file or shape.
        name: String,
        /// Which normal and why.
        message: String,
    },
    /// Some edge has only one triangle, so the surface has a hole.
    #[error(
        "{name}: the mesh is open: {count} boundary edges (one joins vertices {} and {}); \
         if the file repeats vertices along seams, Mesh::weld may close it",
        edge[0], edge[1]
    )]
    Open {
        /// The mesh.
        name: String,
        /// Number of boundary edges.
        count: usize,
        /// One of them.
        edge: [u32; 2],
    },
    /// Some edge has more than two triangles.
    #[error(
        "{name}: the mesh is not manifold: {count} edges have more than two triangles \
         (one joins vertices {} and {})",
        edge[0], edge[1]
    )]
    NonManifold {
        /// The mesh.
        name: String,
        /// Number of such edges.
        count: usize,
        /// One of them.
        edge: [u32; 2],
    },
    /// Neighbouring triangles disagree on which side is out.
    #[error(
        "{name}: the mesh is not consistently oriented: {count} edges are traversed in the \
         same direction by both their triangles (one joins vertices {} and {})",
        edge[0], edge[1]
    )]
    Misoriented {
        /// The mesh.
        name: String,
        /// Number of such edges.
        count: usize,
        /// One of them.
        edge: [u32; 2],
    },
    /// A closed mesh whose triangles face inward (or enclose nothing).
    #[error("{name}: the mesh faces inward (signed volume {volume:e} is not positive); Mesh::flip turns it outward")]
    InsideOut {
        /// The mesh.
        name: String,
        /// Its signed volume.
        volume: f64,
    },
    /// A parameter of a procedural shape or a transform is out of range.
    #[error("{name}: {message}")]
    InvalidParameter {
        /// The shape or operation.
        name: String,
        /// What is wrong.
        message: String,
    },
}
