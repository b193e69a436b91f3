//! Grid geometry: resolution, world-space bounds and the world <-> voxel maps.
//!
//! # Cell-centre convention
//! The grid covers the axis-aligned box `[min, max]` with `dims[a]` cells along
//! axis `a`, each `spacing[a] = (max[a] - min[a]) / dims[a]` wide. Sample
//! `(i, j, k)` is the value at the **centre** of its cell,
//! `min + (i + 0.5, j + 0.5, k + 0.5) * spacing`. The continuous voxel
//! coordinate of a world point is therefore `u = (x - min) / spacing - 0.5`,
//! so that cell centres sit on whole numbers and trilinear interpolation
//! between centres is the natural reconstruction. Within half a cell of the
//! bounds the nearest centre value is held (clamped), not extrapolated.

use eikon_shader::{layout, Layout, Module};
use glam::DVec3;

/// Geometry of a regular voxel grid (see the module docs for the convention).
#[derive(Clone, Debug, PartialEq)]
pub struct GridGeometry {
    /// Number of cells along x, y, z.
    pub dims: [usize; 3],
    /// World-space lower corner of the covered box.
    pub min: DVec3,
    /// World-space upper corner of the covered box.
    pub max: DVec3,
}

impl GridGeometry {
    /// A grid of `dims` cells covering `[min, max]`.
    pub fn new(dims: [usize; 3], min: DVec3, max: DVec3) -> Self {
        Self { dims, min, max }
    }

    /// Cell size along each axis, in world units.
    pub fn spacing(&self) -> DVec3 {
        (self.max - self.min)
            / DVec3::new(
                self.dims[0] as f64,
                self.dims[1] as f64,
                self.dims[2] as f64,
            )
    }

    /// The smallest cell edge: the length a step "in voxels" is measured in.
    pub fn voxel_size(&self) -> f64 {
        self.spacing().min_element()
    }

    /// Total number of cells.
    pub fn voxel_count(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    /// World position of the centre of cell `(i, j, k)`.
    pub fn voxel_center(&self, i: usize, j: usize, k: usize) -> DVec3 {
        self.min + (DVec3::new(i as f64, j as f64, k as f64) + 0.5) * self.spacing()
    }

    /// The cell containing `p`, or `None` outside the bounds (a point on
    /// the upper faces belongs to no cell).
    #[inline]
    pub fn cell_of(&self, p: DVec3) -> Option<[usize; 3]> {
        let u = (p - self.min) / self.spacing();
        if !u.cmpge(DVec3::ZERO).all() {
            return None;
        }
        let c = [u.x as usize, u.y as usize, u.z as usize];
        (c[0] < self.dims[0] && c[1] < self.dims[1] && c[2] < self.dims[2]).then_some(c)
    }

    /// Index of cell `(i, j, k)` in a C-order (x slowest, z fastest) array.
    #[inline]
    pub fn flat_index(&self, i: usize, j: usize, k: usize) -> usize {
        (i * self.dims[1] + j) * self.dims[2] + k
    }

    /// Trilinear weights of world point `p` (cell-centre convention, the
    /// edge value held in the outer half cell), to read any number of
    /// fields on this grid with one weight computation.
    #[inline]
    pub fn trilinear(&self, p: DVec3) -> Trilinear {
        let [nx, ny, nz] = self.dims;
        let hi = DVec3::new(nx as f64, ny as f64, nz as f64) - 1.0;
        let u = self.world_to_voxel(p).clamp(DVec3::ZERO, hi);
        // u >= 0, so truncation is floor. The lower corner stops one short
        // of the last cell; an axis of one cell has stride 0.
        let i = (u.x as usize).min(nx.saturating_sub(2));
        let j = (u.y as usize).min(ny.saturating_sub(2));
        let k = (u.z as usize).min(nz.saturating_sub(2));
        let f = u - DVec3::new(i as f64, j as f64, k as f64);
        let sx = if nx > 1 { ny * nz } else { 0 };
        let sy = if ny > 1 { nz } else { 0 };
        let sz = usize::from(nz > 1);
        let base = self.flat_index(i, j, k);
        let (wx, wy, wz) = ([1.0 - f.x, f.x], [1.0 - f.y, f.y], [1.0 - f.z, f.z]);
        let mut t = Trilinear {
            cell: [0; 8],
            weight: [0.0; 8],
        };
        for corner in 0..8 {
            let (dx, dy, dz) = (corner & 1, (corner >> 1) & 1, (corner >> 2) & 1);
            t.cell[corner] = base + dx * sx + dy * sy + dz * sz;
            t.weight[corner] = wx[dx] * wy[dy] * wz[dz];
        }
        t
    }

    /// Continuous voxel coordinate of a world point (cell centres are integers).
    pub fn world_to_voxel(&self, p: DVec3) -> DVec3 {
        (p - self.min) / self.spacing() - 0.5
    }

    /// World point of a continuous voxel coordinate (inverse of [`Self::world_to_voxel`]).
    pub fn voxel_to_world(&self, u: DVec3) -> DVec3 {
        self.min + (u + 0.5) * self.spacing()
    }

    /// Whether `p` lies inside the closed bounds.
    pub fn contains(&self, p: DVec3) -> bool {
        p.cmpge(self.min).all() && p.cmple(self.max).all()
    }

    /// Length of the bounds' diagonal.
    pub fn diagonal(&self) -> f64 {
        (self.max - self.min).length()
    }

    /// Parametric interval `[t0, t1]` over which the line `o + t d` lies inside
    /// the bounds (slab test), or `None` if it misses them.
    pub fn clip_line(&self, o: DVec3, d: DVec3) -> Option<(f64, f64)> {
        let mut t0 = f64::NEG_INFINITY;
        let mut t1 = f64::INFINITY;
        for a in 0..3 {
            if d[a] == 0.0 {
                if o[a] < self.min[a] || o[a] > self.max[a] {
                    return None;
                }
            } else {
                let inv = 1.0 / d[a];
                let (mut ta, mut tb) = ((self.min[a] - o[a]) * inv, (self.max[a] - o[a]) * inv);
                if ta > tb {
                    std::mem::swap(&mut ta, &mut tb);
                }
                t0 = t0.max(ta);
                t1 = t1.min(tb);
            }
        }
        (t0 <= t1).then_some((t0, t1))
    }
}

/// The eight cells around a point and their trilinear weights (see
/// [`GridGeometry::trilinear`]).
#[derive(Clone, Copy, Debug)]
pub struct Trilinear {
    /// Flat (C-order) cell indices.
    pub cell: [usize; 8],
    /// Weights, summing to 1.
    pub weight: [f64; 8],
}

impl Trilinear {
    /// Interpolate a scalar field stored C-order, one value per cell.
    #[inline]
    pub fn scalar(&self, a: &[f32]) -> f64 {
        (0..8)
            .map(|k| self.weight[k] * a[self.cell[k]] as f64)
            .sum()
    }

    /// Interpolate a 3-vector field stored C-order, three values per cell.
    #[inline]
    pub fn vec3(&self, a: &[f32]) -> DVec3 {
        let mut out = DVec3::ZERO;
        for k in 0..8 {
            let w = self.weight[k];
            if w != 0.0 {
                let c = 3 * self.cell[k];
                out += DVec3::new(a[c] as f64, a[c + 1] as f64, a[c + 2] as f64) * w;
            }
        }
        out
    }
}

layout! {
    /// The grid as a kernel reads it (`GridGpu` in WGSL), in f32: see
    /// [`GridGeometry`] for the convention, and [`WGSL`] for the functions
    /// over it.
    pub struct GridGpu {
        /// Lower corner.
        pub min: [f32; 3],
        /// The smallest cell edge ([`GridGeometry::voxel_size`]).
        pub voxel: f32,
        /// Upper corner.
        pub max: [f32; 3],
        /// Length of the bounds' diagonal.
        pub diagonal: f32,
        /// Cell size per axis.
        pub spacing: [f32; 3],
        /// Padding (a `vec3` is aligned to 16 bytes in WGSL).
        pub pad0: f32,
        /// `1 / spacing`, computed in f64.
        pub inv_spacing: [f32; 3],
        /// Padding.
        pub pad1: f32,
        /// Cells per axis.
        pub dims: [u32; 3],
        /// Padding.
        pub pad2: u32,
    }
}

impl GridGpu {
    /// `g` in f32.
    pub fn new(g: &GridGeometry) -> Self {
        let f3 = |v: DVec3| v.to_array().map(|x| x as f32);
        GridGpu {
            min: f3(g.min),
            voxel: g.voxel_size() as f32,
            max: f3(g.max),
            diagonal: g.diagonal() as f32,
            spacing: f3(g.spacing()),
            inv_spacing: f3(1.0 / g.spacing()),
            dims: g.dims.map(|d| d as u32),
            ..Default::default()
        }
    }
}

fn grid_declarations() -> String {
    GridGpu::declaration()
}

/// The WGSL of the grid: `GridGpu`, containment, the slab test,
/// cells, and the trilinear reconstruction in the cell-centre convention
/// (`VoxelField::sample`'s order and [`Trilinear`]'s weights).
pub static WGSL: Module = Module {
    name: "grid",
    requires: &[],
    declarations: grid_declarations,
    text: include_str!("geometry.wgsl"),
};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centre_convention_round_trips() {
        let g = GridGeometry::new([4, 8, 2], DVec3::splat(-1.0), DVec3::new(1.0, 3.0, 0.0));
        assert_eq!(g.spacing(), DVec3::new(0.5, 0.5, 0.5));
        let c = g.voxel_center(0, 0, 0);
        assert_eq!(c, DVec3::new(-0.75, -0.75, -0.75));
        assert_eq!(g.world_to_voxel(c), DVec3::ZERO);
        let p = DVec3::new(0.3, 1.7, -0.2);
        assert!((g.voxel_to_world(g.world_to_voxel(p)) - p).length() < 1e-12);
    }

    #[test]
    fn trilinear_weights_reproduce_a_linear_field() {
        let g = GridGeometry::new([5, 4, 3], DVec3::splat(-1.0), DVec3::new(1.5, 1.0, 0.5));
        let f = |p: DVec3| 2.0 * p.x - 3.0 * p.y + 0.5 * p.z + 1.0;
        let mut a = vec![0f32; g.voxel_count()];
        for i in 0..5 {
            for j in 0..4 {
                for k in 0..3 {
                    a[g.flat_index(i, j, k)] = f(g.voxel_center(i, j, k)) as f32;
                }
            }
        }
        // Away from the outer half cell, trilinear reproduces a linear field.
        let p = DVec3::new(0.1, -0.2, -0.3);
        let t = g.trilinear(p);
        assert!((t.weight.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert!((t.scalar(&a) - f(p)).abs() < 1e-5, "{}", t.scalar(&a));
    }

    #[test]
    fn clip_line_enters_and_exits() {
        let g = GridGeometry::new([2, 2, 2], DVec3::ZERO, DVec3::ONE);
        let (t0, t1) = g.clip_line(DVec3::new(-1.0, 0.5, 0.5), DVec3::X).unwrap();
        assert_eq!((t0, t1), (1.0, 2.0));
        assert!(g.clip_line(DVec3::new(-1.0, 2.0, 0.5), DVec3::X).is_none());
    }
}
