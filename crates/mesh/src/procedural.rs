//! Procedural closed meshes: spheres, the bumpy sphere, solids of revolution,
//! boxes.
//!
//! All come out watertight and outward-facing. Shapes are built about the
//! origin (revolutions about the y axis); [`Mesh::transform`] places them.
//! Smooth shapes carry their exact normals where they are known (spheres,
//! bumpy sphere), so interpolated shading normals are as good as the
//! tessellation allows.

use crate::mesh::Mesh;
use crate::MeshError;
use glam::{DVec2, DVec3};
use std::collections::HashMap;
use std::f64::consts::PI;

fn invalid(name: &str, message: String) -> MeshError {
    MeshError::InvalidParameter {
        name: name.to_string(),
        message,
    }
}

/// The most triangles a procedural mesh may have (about 2 GB of mesh data).
const MAX_TRIANGLES: u64 = 1 << 25;

/// A box with half-extents `half` centred at the origin: 8 vertices, 12
/// triangles, normals along the corner diagonals.
pub fn cuboid(half: DVec3) -> Result<Mesh, MeshError> {
    let name = format!("box {half}");
    if !(half.is_finite() && half.min_element() > 0.0) {
        return Err(invalid(&name, "half-extents must be finite and > 0".into()));
    }
    let positions: Vec<DVec3> = (0..8)
        .map(|i| {
            let s = |bit: u32| if i & (1 << bit) != 0 { 1.0 } else { -1.0 };
            half * DVec3::new(s(0), s(1), s(2))
        })
        .collect();
    // Quads counter-clockwise seen from outside.
    let quads = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    let triangles = quads
        .iter()
        .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
        .collect();
    Mesh::new(name, positions, triangles)
}

/// The 12 vertices and 20 outward faces of the unit icosahedron.
fn icosahedron() -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let g = (1.0 + 5f64.sqrt()) / 2.0;
    let v: Vec<DVec3> = [
        [-1.0, g, 0.0],
        [1.0, g, 0.0],
        [-1.0, -g, 0.0],
        [1.0, -g, 0.0],
        [0.0, -1.0, g],
        [0.0, 1.0, g],
        [0.0, -1.0, -g],
        [0.0, 1.0, -g],
        [g, 0.0, -1.0],
        [g, 0.0, 1.0],
        [-g, 0.0, -1.0],
        [-g, 0.0, 1.0],
    ]
    .iter()
    .map(|a| DVec3::from_array(*a).normalize())
    .collect();
    let mut f: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    // Orient from the geometry rather than trusting the table.
    for t in &mut f {
        let [a, b, c] = t.map(|i| v[i as usize]);
        if (b - a).cross(c - a).dot(a + b + c) < 0.0 {
            t.swap(1, 2);
        }
    }
    (v, f)
}

/// Unit directions and triangles of a class-I geodesic sphere: each
/// icosahedron face is cut into `frequency^2` triangles on a flat grid whose
/// points are then projected onto the sphere. Edge points are computed from
/// the edge's lower-indexed end, so both faces of an edge share them exactly.
fn geodesic_directions(frequency: u32) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let (ico, faces) = icosahedron();
    let n = frequency as usize;
    let mut dirs: Vec<DVec3> = ico.clone();
    let mut edge_points: HashMap<(u32, u32, usize), u32> = HashMap::new();
    let mut triangles = Vec::with_capacity(20 * n * n);
    let mut local = vec![0u32; (n + 1) * (n + 1)];
    for f in &faces {
        let [ia, ib, ic] = *f;
        let [a, b, c] = f.map(|i| ico[i as usize]);
        let mut edge_vertex = |u: u32, v: u32, k: usize, dirs: &mut Vec<DVec3>| -> u32 {
            // Position k of n along u -> v, keyed from the smaller index.
            let (lo, hi, kk) = if u < v { (u, v, k) } else { (v, u, n - k) };
            *edge_points.entry((lo, hi, kk)).or_insert_with(|| {
                let p = ico[lo as usize].lerp(ico[hi as usize], kk as f64 / n as f64);
                dirs.push(p.normalize());
                (dirs.len() - 1) as u32
            })
        };
        for i in 0..=n {
            for j in 0..=(n - i) {
                let id = if i == 0 && j == 0 {
                    ia
                } else if i == n {
                    ib
                } else if j == n {
                    ic
                } else if j == 0 {
                    edge_vertex(ia, ib, i, &mut dirs)
                } else if i == 0 {
                    edge_vertex(ia, ic, j, &mut dirs)
                } else if i + j == n {
                    edge_vertex(ib, ic, j, &mut dirs)
                } else {
                    let p = a + (b - a) * (i as f64 / n as f64) + (c - a) * (j as f64 / n as f64);
                    dirs.push(p.normalize());
                    (dirs.len() - 1) as u32
                };
                local[i * (n + 1) + j] = id;
            }
        }
        let at = |i: usize, j: usize| local[i * (n + 1) + j];
        for i in 0..n {
            for j in 0..(n - i) {
                triangles.push([at(i, j), at(i + 1, j), at(i, j + 1)]);
                if i + j + 1 < n {
                    triangles.push([at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)]);
                }
            }
        }
    }
    (dirs, triangles)
}

fn check_frequency(name: &str, frequency: u32) -> Result<(), MeshError> {
    if frequency == 0 || 20 * (frequency as u64).pow(2) > MAX_TRIANGLES {
        return Err(invalid(
            name,
            format!(
                "frequency must be in 1..={}, not {frequency}",
                ((MAX_TRIANGLES / 20) as f64).sqrt() as u64
            ),
        ));
    }
    Ok(())
}

fn check_radius(name: &str, radius: f64) -> Result<(), MeshError> {
    if !(radius.is_finite() && radius > 0.0) {
        return Err(invalid(
            name,
            format!("radius must be finite and > 0, not {radius}"),
        ));
    }
    Ok(())
}

/// Geodesic sphere of `radius` about the origin with `20 * frequency^2`
/// triangles, vertices on the sphere and exact (radial) normals.
pub fn geodesic_sphere(radius: f64, frequency: u32) -> Result<Mesh, MeshError> {
    let name = format!("geodesic sphere (radius {radius}, frequency {frequency})");
    check_radius(&name, radius)?;
    check_frequency(&name, frequency)?;
    let (dirs, triangles) = geodesic_directions(frequency);
    let positions = dirs.iter().map(|d| *d * radius).collect();
    Mesh::with_normals(name, positions, dirs, triangles)
}

/// Icosphere of `radius` about the origin: the icosahedron subdivided
/// `level` times (each triangle into four), `20 * 4^level` triangles, exact
/// normals. Level 0 is the icosahedron; at most level 10.
///
/// Subdividing in one step on a `2^level` grid gives the same vertex count
/// and connectivity as repeated midpoint splitting.
pub fn icosphere(radius: f64, level: u32) -> Result<Mesh, MeshError> {
    if level > 10 {
        return Err(invalid(
            &format!("icosphere (level {level})"),
            format!("subdivision level must be at most 10, not {level}"),
        ));
    }
    let mut m = geodesic_sphere(radius, 1 << level)?;
    m.set_name(format!("icosphere (radius {radius}, level {level})"));
    Ok(m)
}

/// One bump of a [`BumpySphere`]: `weight * sin(frequency * (u . direction) + phase)`
/// for a unit direction `u`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bump {
    /// Unit axis the bump varies along.
    pub direction: DVec3,
    /// Angular frequency (radians per unit of `u . direction`).
    pub frequency: f64,
    /// Phase in radians.
    pub phase: f64,
    /// Weight; the weights of a sphere sum to 1 in absolute value.
    pub weight: f64,
}

/// The papers' hardest case ([Walter09 fig 7]): a star-shaped
/// solid whose radius in unit direction `u` is
/// `radius * (1 + amplitude * sum_k weight_k sin(frequency_k (u . d_k) + phase_k))`.
///
/// Each term is smooth on the sphere, so the surface is smooth, and since
/// the weights sum to 1 the radius stays within `radius * (1 +- amplitude)`.
/// A radial graph never intersects itself, so every tessellation is a valid
/// closed surface. The exact radius, normal and volume are available for
/// checking renderers against.
#[derive(Clone, Debug, PartialEq)]
pub struct BumpySphere {
    radius: f64,
    amplitude: f64,
    bumps: Vec<Bump>,
}

impl BumpySphere {
    /// `bumps` random bumps (1..=64) drawn from `seed`: uniform directions,
    /// frequencies in [2, 6) (a few bumps across the sphere), uniform phases,
    /// weights in [0.5, 1) normalized to sum 1. `amplitude` must lie in
    /// [0, 0.9]; the papers' look is around 0.1 to 0.2.
    pub fn new(radius: f64, amplitude: f64, bumps: usize, seed: u64) -> Result<Self, MeshError> {
        let name = format!("bumpy sphere (radius {radius}, amplitude {amplitude}, seed {seed})");
        check_radius(&name, radius)?;
        if !(0.0..=0.9).contains(&amplitude) {
            return Err(invalid(
                &name,
                format!("amplitude must lie in [0, 0.9], not {amplitude}"),
            ));
        }
        if !(1..=64).contains(&bumps) {
            return Err(invalid(
                &name,
                format!("bump count must lie in 1..=64, not {bumps}"),
            ));
        }
        // SplitMix64: a seed gives the same bumps on every platform.
        let mut rng = eikon_rng::SplitMix64::new(seed);
        let mut list: Vec<Bump> = (0..bumps)
            .map(|_| {
                // Uniform on the sphere: z uniform, azimuth uniform.
                let z = 2.0 * rng.unit() - 1.0;
                let phi = 2.0 * PI * rng.unit();
                let s = (1.0 - z * z).max(0.0).sqrt();
                Bump {
                    direction: DVec3::new(s * phi.cos(), s * phi.sin(), z),
                    frequency: 2.0 + 4.0 * rng.unit(),
                    phase: 2.0 * PI * rng.unit(),
                    weight: 0.5 + 0.5 * rng.unit(),
                }
            })
            .collect();
        let total: f64 = list.iter().map(|b| b.weight).sum();
        for b in &mut list {
            b.weight /= total;
        }
        Ok(Self {
            radius,
            amplitude,
            bumps: list,
        })
    }

    /// The mean radius.
    pub fn radius(&self) -> f64 {
        self.radius
    }

    /// The relative amplitude.
    pub fn amplitude(&self) -> f64 {
        self.amplitude
    }

    /// The bumps.
    pub fn bumps(&self) -> &[Bump] {
        &self.bumps
    }

    /// The bump sum f(u) in [-1, 1] and its ambient gradient at unit `u`.
    fn field(&self, u: DVec3) -> (f64, DVec3) {
        let mut f = 0.0;
        let mut grad = DVec3::ZERO;
        for b in &self.bumps {
            let arg = b.frequency * u.dot(b.direction) + b.phase;
            f += b.weight * arg.sin();
            grad += b.direction * (b.weight * b.frequency * arg.cos());
        }
        (f, grad)
    }

    /// Radius of the surface in direction `dir` (normalized here; the zero
    /// vector has no direction and gives NaN).
    pub fn radius_at(&self, dir: DVec3) -> f64 {
        let u = dir.normalize();
        self.radius * (1.0 + self.amplitude * self.field(u).0)
    }

    /// The surface point in direction `dir`.
    pub fn surface_point(&self, dir: DVec3) -> DVec3 {
        let u = dir.normalize();
        u * self.radius_at(u)
    }

    /// Exact outward unit normal at the surface point in direction `dir`.
    ///
    /// For a radial graph `p(u) = r(u) u` the normal is parallel to
    /// `u - grad_s r / r`, with `grad_s` the gradient tangent to the unit
    /// sphere.
    pub fn normal_at(&self, dir: DVec3) -> DVec3 {
        let u = dir.normalize();
        let (f, grad) = self.field(u);
        let r = self.radius * (1.0 + self.amplitude * f);
        let g = grad * (self.radius * self.amplitude);
        let tangential = g - u * g.dot(u);
        (u - tangential / r).normalize()
    }

    /// Whether `p` lies strictly inside.
    pub fn contains(&self, p: DVec3) -> bool {
        let d = p.length();
        d == 0.0 || d < self.radius_at(p)
    }

    /// Enclosed volume `(1/3) * integral of r^3 over the unit sphere`, by
    /// the midpoint rule on 1024 polar by 2048 azimuthal cells (relative
    /// error below 1e-6).
    pub fn volume(&self) -> f64 {
        let (nt, np) = (1024usize, 2048usize);
        let (dt, dp) = (PI / nt as f64, 2.0 * PI / np as f64);
        let mut sum = 0.0;
        for i in 0..nt {
            let theta = (i as f64 + 0.5) * dt;
            let (st, ct) = theta.sin_cos();
            let mut ring = 0.0;
            for j in 0..np {
                let (sp, cp) = ((j as f64 + 0.5) * dp).sin_cos();
                ring += self.radius_at(DVec3::new(st * cp, st * sp, ct)).powi(3);
            }
            sum += ring * st;
        }
        sum * dt * dp / 3.0
    }

    /// A geodesic tessellation with `20 * frequency^2` triangles, vertices on
    /// the surface and exact normals. Frequency 22 gives the 9680 triangles
    /// of Walter et al.'s bumpy sphere.
    pub fn mesh(&self, frequency: u32) -> Result<Mesh, MeshError> {
        let name = format!(
            "bumpy sphere (radius {}, amplitude {}, {} bumps, frequency {frequency})",
            self.radius,
            self.amplitude,
            self.bumps.len()
        );
        check_frequency(&name, frequency)?;
        let (dirs, triangles) = geodesic_directions(frequency);
        let positions = dirs.iter().map(|&u| u * self.radius_at(u)).collect();
        let normals = dirs.iter().map(|&u| self.normal_at(u)).collect();
        Mesh::with_normals(name, positions, normals, triangles)
    }
}

/// Whether closed segments `a0-a1` and `b0-b1` share a point (exact
/// orientation tests, touching counts).
fn segments_touch(a0: DVec2, a1: DVec2, b0: DVec2, b1: DVec2) -> bool {
    let orient = |p: DVec2, q: DVec2, r: DVec2| (q - p).perp_dot(r - p);
    let on = |p: DVec2, q: DVec2, r: DVec2| {
        r.x >= p.x.min(q.x) && r.x <= p.x.max(q.x) && r.y >= p.y.min(q.y) && r.y <= p.y.max(q.y)
    };
    let (d1, d2) = (orient(b0, b1, a0), orient(b0, b1, a1));
    let (d3, d4) = (orient(a0, a1, b0), orient(a0, a1, b1));
    if ((d1 > 0.0 && d2 < 0.0) || (d1 < 0.0 && d2 > 0.0))
        && ((d3 > 0.0 && d4 < 0.0) || (d3 < 0.0 && d4 > 0.0))
    {
        return true;
    }
    (d1 == 0.0 && on(b0, b1, a0))
        || (d2 == 0.0 && on(b0, b1, a1))
        || (d3 == 0.0 && on(a0, a1, b0))
        || (d4 == 0.0 && on(a0, a1, b1))
}

/// Cleans and validates a closed (radius, height) profile: drops repeated
/// consecutive points, then requires at least 3 points, finite values,
/// radius >= 0, non-zero area and no self-intersection.
fn clean_profile(name: &str, profile: &[DVec2]) -> Result<Vec<DVec2>, MeshError> {
    for (i, q) in profile.iter().enumerate() {
        if !q.is_finite() {
            return Err(invalid(
                name,
                format!("profile point {i} is not finite: {q}"),
            ));
        }
        if q.x < 0.0 {
            return Err(invalid(
                name,
                format!("profile point {i} has radius {} < 0", q.x),
            ));
        }
    }
    let mut pts: Vec<DVec2> = Vec::with_capacity(profile.len());
    for &q in profile {
        if pts.last() != Some(&q) {
            pts.push(q);
        }
    }
    while pts.len() > 1 && pts.first() == pts.last() {
        pts.pop();
    }
    let n = pts.len();
    if n < 3 {
        return Err(invalid(
            name,
            "a profile needs at least 3 distinct [radius, height] points".into(),
        ));
    }
    let area2: f64 = (0..n).map(|i| pts[i].perp_dot(pts[(i + 1) % n])).sum();
    if area2.abs() < 1e-12 {
        return Err(invalid(name, "the profile polygon encloses no area".into()));
    }
    for i in 0..n {
        let (a0, a1) = (pts[i], pts[(i + 1) % n]);
        // Adjacent edges share a point; they must not fold back onto each other.
        let a2 = pts[(i + 2) % n];
        if (a1 - a0).perp_dot(a2 - a1) == 0.0 && (a1 - a0).dot(a2 - a1) < 0.0 {
            return Err(invalid(
                name,
                format!(
                    "profile edges {i} and {} fold back onto each other",
                    (i + 1) % n
                ),
            ));
        }
        for j in (i + 2)..n {
            if i == 0 && j == n - 1 {
                continue;
            }
            if segments_touch(a0, a1, pts[j], pts[(j + 1) % n]) {
                return Err(invalid(
                    name,
                    format!("profile edges {i} and {j} cross or touch; the polygon must be simple"),
                ));
            }
        }
    }
    Ok(pts)
}

/// Solid of revolution about the y axis: the closed polygon `profile` of
/// (radius, height) points swept around the axis, as the grid crate's
/// `Shape::Revolution` reads it (local frame, before `base` and `rot`).
///
/// A profile point on the axis (radius 0) becomes one pole vertex; an edge
/// from the axis out to radius r becomes a cone or, when level, a flat disc
/// cap, and an edge along the axis sweeps to nothing. The polygon may run
/// either way round; the mesh always faces outward. `segments` (3..=65536)
/// vertices make up each ring. Normals are angle-weighted, so a sharp profile
/// corner gets the average of its two sides.
pub fn revolution(profile: &[DVec2], segments: u32) -> Result<Mesh, MeshError> {
    let name = format!(
        "solid of revolution ({} profile points, {segments} segments)",
        profile.len()
    );
    if !(3..=65536).contains(&segments) {
        return Err(invalid(
            &name,
            format!("segments must lie in 3..=65536, not {segments}"),
        ));
    }
    let pts = clean_profile(&name, profile)?;
    let s = segments as usize;
    if 2 * segments as u64 * pts.len() as u64 > MAX_TRIANGLES {
        return Err(invalid(&name, "too many triangles".into()));
    }
    let (sin, cos): (Vec<f64>, Vec<f64>) = (0..s)
        .map(|k| (2.0 * PI * k as f64 / s as f64).sin_cos())
        .unzip();
    let mut positions = Vec::new();
    // First vertex of each profile point: its pole or the start of its ring.
    let mut first = Vec::with_capacity(pts.len());
    for q in &pts {
        first.push(positions.len() as u32);
        if q.x == 0.0 {
            positions.push(DVec3::new(0.0, q.y, 0.0));
        } else {
            for k in 0..s {
                positions.push(DVec3::new(q.x * cos[k], q.y, q.x * sin[k]));
            }
        }
    }
    let vertex = |i: usize, k: usize| {
        if pts[i].x == 0.0 {
            first[i]
        } else {
            first[i] + (k % s) as u32
        }
    };
    let mut triangles = Vec::new();
    let n = pts.len();
    for i in 0..n {
        let j = (i + 1) % n;
        let (pole_i, pole_j) = (pts[i].x == 0.0, pts[j].x == 0.0);
        for k in 0..s {
            // The quad (i,k) (i,k+1) (j,k+1) (j,k); a pole collapses its side.
            let (a, b, c, d) = (
                vertex(i, k),
                vertex(i, k + 1),
                vertex(j, k + 1),
                vertex(j, k),
            );
            match (pole_i, pole_j) {
                (true, true) => {}
                (true, false) => triangles.push([a, c, d]),
                (false, true) => triangles.push([a, b, c]),
                (false, false) => {
                    triangles.push([a, b, c]);
                    triangles.push([a, c, d]);
                }
            }
        }
    }
    let mut mesh = Mesh::new(name, positions, triangles)?;
    // The winding follows the polygon's direction; flip if that was inward.
    if mesh.signed_volume() < 0.0 {
        mesh.flip();
    }
    Ok(mesh)
}

/// Solid of revolution from an open polyline of (radius, height) points:
/// an end off the axis is closed by a flat cap (a disc at the end's height
/// down to the axis), then the closed profile goes to [`revolution`]. A
/// polyline whose ends are on the axis needs no caps.
pub fn revolution_open(profile: &[DVec2], segments: u32) -> Result<Mesh, MeshError> {
    let mut closed = Vec::with_capacity(profile.len() + 2);
    if let (Some(f), Some(l)) = (profile.first(), profile.last()) {
        if f.x != 0.0 {
            closed.push(DVec2::new(0.0, f.y));
        }
        closed.extend_from_slice(profile);
        if l.x != 0.0 {
            closed.push(DVec2::new(0.0, l.y));
        }
    }
    revolution(&closed, segments)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn icosahedron_is_watertight() {
        let m = icosphere(1.0, 0).unwrap();
        assert_eq!(m.triangle_count(), 20);
        assert_eq!(m.vertex_count(), 12);
        m.require_closed().unwrap();
    }

    #[test]
    fn geodesic_counts() {
        for f in [1u32, 2, 3, 5, 22] {
            let m = geodesic_sphere(2.0, f).unwrap();
            assert_eq!(m.triangle_count(), 20 * (f * f) as usize);
            // Euler: V - E + F = 2 with E = 3F/2.
            assert_eq!(m.vertex_count(), 10 * (f * f) as usize + 2);
            m.require_closed().unwrap();
        }
    }

    #[test]
    fn bad_parameters_are_errors() {
        assert!(icosphere(0.0, 2).is_err());
        assert!(icosphere(f64::NAN, 2).is_err());
        assert!(icosphere(1.0, 11).is_err());
        assert!(geodesic_sphere(1.0, 0).is_err());
        assert!(BumpySphere::new(1.0, 1.5, 5, 0).is_err());
        assert!(BumpySphere::new(1.0, 0.1, 0, 0).is_err());
        assert!(cuboid(DVec3::new(1.0, 0.0, 1.0)).is_err());
        let sq = [
            DVec2::new(0.0, 0.0),
            DVec2::new(1.0, 0.0),
            DVec2::new(1.0, 1.0),
        ];
        assert!(revolution(&sq, 2).is_err());
        assert!(revolution(&sq[..2], 8).is_err());
        let neg = [
            DVec2::new(-1.0, 0.0),
            DVec2::new(1.0, 0.0),
            DVec2::new(1.0, 1.0),
        ];
        assert!(revolution(&neg, 8).is_err());
        // A bow tie crosses itself.
        let bow = [
            DVec2::new(0.5, 0.0),
            DVec2::new(1.0, 1.0),
            DVec2::new(1.0, 0.0),
            DVec2::new(0.2, 1.5),
        ];
        let e = revolution(&bow, 8).unwrap_err();
        assert!(e.to_string().contains("simple"), "{e}");
        let flat = [
            DVec2::new(0.0, 0.0),
            DVec2::new(1.0, 0.0),
            DVec2::new(2.0, 0.0),
        ];
        assert!(revolution(&flat, 8).is_err());
    }

    #[test]
    fn cuboid_is_watertight() {
        let m = cuboid(DVec3::new(1.0, 2.0, 3.0)).unwrap();
        let r = m.require_closed().unwrap();
        assert!((r.signed_volume - 48.0).abs() < 1e-12);
    }
}
