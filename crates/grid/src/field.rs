//! The voxel medium: index field(s) with gradient, attenuation, albedo,
//! Henyey-Greenstein g, emission and the boundary indicator; and the two
//! ways to sample an index field, from voxels or exactly from the scene.
//!
//! # Gradient
//! The gradient is stored per cell as a central difference of the
//! Gaussian-smoothed index (the paper's choice), sampled trilinearly like n
//! itself, so the force on a ray is continuous. The trilinear interpolant's
//! own derivative would be piecewise constant across a cell and jump at
//! every cell face, bending rays unevenly and breaking RK4's order.
//!
//! Two refinements keep the stored gradient consistent with n:
//! * the stencil is isotropic (`smooth::isotropic_gradient`), so its error
//!   is parallel to the normal of an interface instead of leaning;
//! * what is differenced is `n^2 / 2`, and grad n is recovered as
//!   `grad(n^2/2) / n` when sampled. Along a ray `d(v_n^2)/dy = 2 grad(n^2/2)`
//!   in both forms of the ray equation, and the trilinear integral of a
//!   central difference telescopes, so crossing a flat interface changes
//!   `|v|^2` by exactly the jump in `n^2`: the invariant `|v| = n` and with it
//!   Snell's law hold to the integrator's accuracy, not the stencil's.
//!
//! See docs/ARCHITECTURE.md.
//!
//! # Units
//! Lengths are world units (the scene's). `extinction` is sigma_t per world
//! unit, so a path of length d keeps `exp(-sigma_t d)`. The gradient is per
//! world unit. The boundary indicator is per world unit and integrates to
//! one across an interface ([Ihrke07 eq 2]'s Dirac delta).

use crate::blocks::BlockGrid;
use crate::error::Result;
use crate::geometry::GridGeometry;
use crate::ray::IndexField;
use crate::scene::Scene;
use crate::smooth;
use crate::voxelize::{self, Raster};
use glam::{DVec3, Vec4};
use ndarray::{s, Array3, Array4, ArrayView3, ArrayView4, Axis};
use rayon::prelude::*;

/// A scene voxelized onto its grid.
#[derive(Clone, Debug)]
pub struct Medium {
    /// Resolution and bounds.
    pub geometry: GridGeometry,
    /// Smoothing sigma applied to n, in voxels.
    pub smoothing: f64,
    /// One array per index channel (1, or 3 = R, G, B with dispersion), of
    /// shape `(nx, ny, nz, 4)`: the smoothed index n, then the gradient of
    /// `n^2 / 2` per world unit (so grad n = that / n; see the module docs).
    pub index: Vec<Array4<f32>>,
    /// RGB extinction sigma_t per world unit, `(nx, ny, nz, 3)`.
    pub extinction: Array4<f32>,
    /// RGB single-scattering albedo, `(nx, ny, nz, 3)`.
    pub albedo: Array4<f32>,
    /// Henyey-Greenstein asymmetry, `(nx, ny, nz)`.
    pub g: Array3<f32>,
    /// RGB emission, `(nx, ny, nz, 3)`.
    pub emission: Array4<f32>,
    /// Discrete Dirac delta of the material boundaries (per world unit).
    pub boundary: Array3<f32>,
    /// Smallest and largest index over all channels ([`Self::index_range`]).
    index_bounds: (f32, f32),
}

/// Progress callback of [`Medium::build_with_progress`]: `(stage, done,
/// total)` units of work; called from worker threads. Building has named
/// stages (rasterize, smooth, ...), so it says which one is running.
pub type BuildProgress<'a> = &'a (dyn Fn(&'static str, u64, u64) + Sync);

/// Memory needed for a medium, in bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MemoryEstimate {
    /// Kept once built.
    pub resident: u128,
    /// Kept once the render properties are released
    /// ([`Medium::release_render_properties`]): what the light simulation
    /// alone holds.
    pub light: u128,
    /// Highest use while building.
    pub peak: u128,
    /// Kept by a medium of the surfaces alone
    /// ([`Medium::build_surfaces_within`]).
    pub surfaces: u128,
    /// Highest use while building that.
    pub surfaces_peak: u128,
}

/// Bytes the operating system reports available (`MemAvailable`), if known.
pub fn available_memory() -> Option<u128> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = info.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u128 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// Human-readable byte count.
pub fn format_bytes(b: u128) -> String {
    let units = ["B", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB"];
    let mut v = b as f64;
    let mut u = 0;
    while v >= 1024.0 && u + 1 < units.len() {
        v /= 1024.0;
        u += 1;
    }
    if u == 0 {
        format!("{b} B")
    } else {
        format!("{v:.1} {}", units[u])
    }
}

/// Halo of cells voxelized around the grid so smoothing and the central
/// difference at the edge see real scene values rather than a clamp.
fn halo(sigma: f64) -> usize {
    smooth::kernel_radius(sigma) + 1
}

impl Medium {
    /// Memory the medium of `scene` takes, resident and while building.
    pub fn memory_estimate(scene: &Scene) -> MemoryEstimate {
        let c = scene.channels() as u128;
        let d = scene.grid.geometry.dims.map(|x| x as u128);
        let p = 2 * halo(scene.grid.smoothing) as u128;
        let voxels = d[0] * d[1] * d[2];
        let padded = (d[0] + p) * (d[1] + p) * (d[2] + p);
        // Index and gradient per channel; extinction, albedo, g, emission,
        // boundary. The light keeps the index, extinction and boundary.
        let resident = voxels * (16 * c + 4 * (3 + 3 + 1 + 3 + 1));
        let light = voxels * (16 * c + 4 * (3 + 1));
        let raster = padded * 4 * voxelize::stride(c as usize, scene.objects.len()) as u128;
        // The boundary indicator alone.
        let surfaces = voxels * 4;
        // The raster, plus one padded scalar field being smoothed.
        MemoryEstimate {
            resident,
            light,
            peak: resident + raster + padded * 4,
            surfaces,
            surfaces_peak: surfaces + raster + padded * 4,
        }
    }

    /// Voxelize `scene`: supersampled rasterization, Gaussian smoothing of n,
    /// central-difference gradient, boundary indicator. Refuses, before
    /// allocating, a grid that would not fit in available memory.
    pub fn build(scene: &Scene) -> Result<Medium> {
        Self::build_with_progress(scene, &|_, _, _| {})
    }

    /// [`Medium::build`], reporting `(stage, done, total)` as it goes.
    pub fn build_with_progress(scene: &Scene, progress: BuildProgress) -> Result<Medium> {
        Self::build_within(scene, available_memory().unwrap_or(u128::MAX), progress)
    }

    /// [`Medium::build_with_progress`] refusing a grid whose build needs
    /// more than `avail` bytes (instead of the memory the system reports).
    pub fn build_within(scene: &Scene, avail: u128, progress: BuildProgress) -> Result<Medium> {
        let est = Self::memory_estimate(scene);
        let built = Build::new(scene, (est.peak, est.resident), avail, progress)?;
        let (raster, pad) = (&built.raster, built.pad);
        let geom = &scene.grid.geometry;
        let sigma = scene.grid.smoothing;
        let [nx, ny, nz] = geom.dims;
        let h = geom.spacing().to_array();

        // Index fields: smooth, then n and the gradient of n^2 / 2.
        let mut index = Vec::with_capacity(raster.channels);
        for c in 0..raster.channels {
            progress("index and gradient", c as u64, raster.channels as u64);
            let mut n = built.extract(c);
            smooth::gaussian(&mut n, sigma);
            let nv = n.view();
            let mut out = Array4::<f32>::zeros((nx, ny, nz, 4));
            out.axis_iter_mut(Axis(0))
                .into_par_iter()
                .enumerate()
                .for_each(|(i, mut plane)| {
                    for j in 0..ny {
                        for k in 0..nz {
                            let (pi, pj, pk) = (i + pad, j + pad, k + pad);
                            // The gradient of n^2 / 2 (see the module docs).
                            let g = smooth::isotropic_gradient(&nv, pi, pj, pk, h, |n| 0.5 * n * n);
                            plane[[j, k, 0]] = nv[[pi, pj, pk]];
                            plane[[j, k, 1]] = g[0] as f32;
                            plane[[j, k, 2]] = g[1] as f32;
                            plane[[j, k, 3]] = g[2] as f32;
                        }
                    }
                });
            index.push(out);
        }
        check_index(scene, index.iter().map(|a| a.slice(s![.., .., .., 0])))?;
        let index_bounds = range(
            index
                .iter()
                .flat_map(|a| a.slice(s![.., .., .., 0]).into_iter().copied()),
        );

        let boundary = built.boundary(scene, progress);
        Ok(Medium {
            geometry: geom.clone(),
            smoothing: sigma,
            index,
            extinction: built.cells3(raster.at(Raster::EXT)),
            albedo: built.cells3(raster.at(Raster::ALB)),
            g: built.cells(raster.at(Raster::G)).to_owned(),
            emission: built.cells3(raster.at(Raster::EMI)),
            boundary,
            index_bounds,
        })
    }

    /// The medium a light simulation with sharp interfaces reads on the
    /// CPU: the boundary indicator ([`crate::region::Regions::clear_of`])
    /// and the index range, nothing else. Its rays and patches read each
    /// region's index and extinction exactly from the scene, so the
    /// smoothed index, its gradient and the voxel extinction (most of what a
    /// cell holds, and most of the build's time) are not made; nor are the
    /// render properties. [`Self::has_voxel_fields`] is false: whatever
    /// samples them refuses it. Refuses, before allocating, a grid whose
    /// build would not fit in `avail` bytes.
    pub fn build_surfaces_within(
        scene: &Scene,
        avail: u128,
        progress: BuildProgress,
    ) -> Result<Medium> {
        let est = Self::memory_estimate(scene);
        let built = Build::new(scene, (est.surfaces_peak, est.surfaces), avail, progress)?;
        let raster = &built.raster;
        // The index as rasterized (each cell the mean of its sub-samples):
        // the smoothed field's values are weighted means of these, so their
        // range holds its range, and equals it wherever each material has
        // a cell of its own.
        let raw: Vec<_> = (0..raster.channels).map(|c| built.cells(c)).collect();
        check_index(scene, raw.iter().map(|a| a.view()))?;
        let index_bounds = range(raw.iter().flat_map(|a| a.iter().copied()));
        let boundary = built.boundary(scene, progress);
        Ok(Medium {
            geometry: scene.grid.geometry.clone(),
            smoothing: scene.grid.smoothing,
            index: (0..raster.channels)
                .map(|_| Array4::zeros((0, 0, 0, 4)))
                .collect(),
            extinction: Array4::zeros((0, 0, 0, 3)),
            albedo: Array4::zeros((0, 0, 0, 3)),
            g: Array3::zeros((0, 0, 0)),
            emission: Array4::zeros((0, 0, 0, 3)),
            boundary,
            index_bounds,
        })
    }

    /// Whether the voxel index, its gradient and the extinction are held:
    /// not in a medium of the surfaces alone
    /// ([`Self::build_surfaces_within`]).
    pub fn has_voxel_fields(&self) -> bool {
        self.extinction.len() == self.geometry.voxel_count() * 3
    }

    /// Number of index channels (1, or 3 with dispersion).
    pub fn channels(&self) -> usize {
        self.index.len()
    }

    /// Whether the properties only renderers read (albedo, g, emission)
    /// are held: not after [`Self::release_render_properties`].
    pub fn has_render_properties(&self) -> bool {
        self.g.dim() == self.boundary.dim()
    }

    /// Panics, saying why, where the render properties were released:
    /// what a renderer calls before it reads them.
    pub fn expect_render_properties(&self) {
        assert!(
            self.has_render_properties(),
            "a medium whose render properties were released (Medium::release_render_properties) cannot be rendered"
        );
    }

    /// Release the properties only renderers read (albedo, g, emission:
    /// 28 of the 60 bytes a cell holds without dispersion), for a medium
    /// that only the light simulation will read (`eikon simulate`). A
    /// renderer refuses the medium afterwards
    /// ([`Self::has_render_properties`]).
    pub fn release_render_properties(&mut self) {
        self.albedo = Array4::zeros((0, 0, 0, 3));
        self.g = Array3::zeros((0, 0, 0));
        self.emission = Array4::zeros((0, 0, 0, 3));
    }

    /// Free the boundary indicator of a medium of the surfaces alone
    /// ([`Self::build_surfaces_within`]) once [`crate::Regions::clear_of`]
    /// has read it: the light with sharp interfaces reads nothing else of
    /// the voxels, and the deposit's counters are allocated after it.
    /// [`crate::Regions::clear_of`] on the medium then goes by the shapes'
    /// distance bounds alone.
    pub fn release_boundary(&mut self) {
        self.boundary = Array3::zeros((0, 0, 0));
    }

    /// Smallest and largest index over all channels.
    pub fn index_range(&self) -> (f32, f32) {
        self.index_bounds
    }

    /// Trilinear sample at world point `p` of an RGB field of this medium
    /// (`extinction`, `albedo` or `emission`), with the cell-centre
    /// convention and clamping of [`VoxelField`].
    pub fn sample_rgb(&self, field: &Array4<f32>, p: DVec3) -> DVec3 {
        let data = field.as_slice().expect("medium fields are contiguous");
        self.geometry.trilinear(p).vec3(data)
    }

    /// Gradient of n (per world unit) at cell `(i, j, k)` of `channel`.
    pub fn gradient_at(&self, channel: usize, i: usize, j: usize, k: usize) -> DVec3 {
        let a = &self.index[channel];
        DVec3::new(
            a[[i, j, k, 1]] as f64,
            a[[i, j, k, 2]] as f64,
            a[[i, j, k, 3]] as f64,
        ) / a[[i, j, k, 0]] as f64
    }

    /// The index field of `channel` for ray tracing (trilinear sampling).
    /// Panics on a medium of the surfaces alone, which holds none
    /// ([`Self::has_voxel_fields`]).
    pub fn field(&self, channel: usize) -> VoxelField<'_> {
        let data = self.index[channel]
            .as_slice()
            .expect("index arrays are contiguous");
        VoxelField::new(data, &self.geometry)
    }
}

/// Refuse, naming the resolution, a build that needs `peak` bytes where
/// `avail` are available.
fn check_fits(scene: &Scene, peak: u128, resident: u128, avail: u128) -> Result<()> {
    if peak > avail {
        return Err(scene.error_at(
            "grid.resolution",
            format!(
                "{:?} voxels need {} to build ({} resident) but only {} of memory is available (or allowed by --max-memory); lower the resolution",
                scene.grid.geometry.dims,
                format_bytes(peak),
                format_bytes(resident),
                format_bytes(avail)
            ),
        ));
    }
    Ok(())
}

/// Every index sample must be finite and positive.
fn check_index<'a>(
    scene: &Scene,
    channels: impl Iterator<Item = ndarray::ArrayView3<'a, f32>>,
) -> Result<()> {
    for (c, a) in channels.enumerate() {
        if let Some(((i, j, k), v)) = a
            .indexed_iter()
            .find(|(_, v)| !(v.is_finite() && **v > 0.0))
        {
            return Err(scene.error_at(
                "object",
                format!("voxelized index of channel {c} is {v} at voxel ({i}, {j}, {k}); it must be finite and > 0"),
            ));
        }
    }
    Ok(())
}

/// Smallest and largest of `values`.
fn range(values: impl Iterator<Item = f32>) -> (f32, f32) {
    values.fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    })
}

/// A scene rasterized on its grid padded by the smoothing's halo: what
/// both builds start from.
struct Build {
    raster: Raster,
    pad: usize,
    padded_dims: [usize; 3],
    dims: [usize; 3],
    sigma: f64,
    h: [f64; 3],
}

impl Build {
    /// Rasterize `scene`, once it is known that the build's `(peak,
    /// resident)` bytes fit in `avail`.
    fn new(
        scene: &Scene,
        (peak, resident): (u128, u128),
        avail: u128,
        progress: BuildProgress,
    ) -> Result<Self> {
        check_fits(scene, peak, resident, avail)?;
        Ok(Self::rasterize(scene, progress))
    }

    fn rasterize(scene: &Scene, progress: BuildProgress) -> Self {
        let geom = &scene.grid.geometry;
        let sigma = scene.grid.smoothing;
        let pad = halo(sigma);
        let spacing = geom.spacing();
        let padded_dims = geom.dims.map(|d| d + 2 * pad);
        let padded = GridGeometry::new(
            padded_dims,
            geom.min - spacing * pad as f64,
            geom.max + spacing * pad as f64,
        );
        Self {
            raster: voxelize::rasterize(scene, &padded, progress),
            pad,
            padded_dims,
            dims: geom.dims,
            sigma,
            h: spacing.to_array(),
        }
    }

    /// The raster as `(padded x, y, z, property)`.
    fn view(&self) -> ArrayView4<'_, f32> {
        let [a, b, c] = self.padded_dims;
        ArrayView4::from_shape((a, b, c, self.raster.stride), &self.raster.data)
            .expect("the raster holds its padded cells")
    }

    /// One property of the raster (at `offset` in a cell), padded.
    fn extract(&self, offset: usize) -> Array3<f32> {
        self.view().slice_move(s![.., .., .., offset]).to_owned()
    }

    /// One property over the grid's own cells (the halo left out).
    fn cells(&self, offset: usize) -> ArrayView3<'_, f32> {
        let (p, [nx, ny, nz]) = (self.pad, self.dims);
        self.view()
            .slice_move(s![p..p + nx, p..p + ny, p..p + nz, offset])
    }

    /// The three properties from `base` on over the grid's own cells
    /// (standard layout).
    fn cells3(&self, base: usize) -> Array4<f32> {
        let (p, [nx, ny, nz]) = (self.pad, self.dims);
        self.view()
            .slice_move(s![p..p + nx, p..p + ny, p..p + nz, base..base + 3])
            .to_owned()
    }

    /// Boundary indicator: half the summed gradient magnitudes of every
    /// material's smoothed coverage. Across an interface between two
    /// materials each coverage goes 0 -> 1 or 1 -> 0, so the sum
    /// integrates to exactly one along the normal ([Ihrke07 eq 2]'s delta).
    fn boundary(&self, scene: &Scene, progress: BuildProgress) -> Array3<f32> {
        let mut boundary = Array3::<f32>::zeros(self.dims);
        let materials = scene.objects.len() as u64 + 1;
        let (pad, h) = (self.pad, self.h);
        for m in 0..=scene.objects.len() {
            progress("boundary indicator", m as u64, materials);
            let mut cov = self.extract(self.raster.at(Raster::COV) + m);
            if cov.iter().all(|&x| x == cov[[0, 0, 0]]) {
                continue;
            }
            smooth::gaussian(&mut cov, self.sigma);
            let cv = cov.view();
            boundary
                .axis_iter_mut(Axis(0))
                .into_par_iter()
                .enumerate()
                .for_each(|(i, mut plane)| {
                    plane.indexed_iter_mut().for_each(|((j, k), b)| {
                        let g =
                            smooth::isotropic_gradient(&cv, i + pad, j + pad, k + pad, h, |c| c);
                        *b += 0.5 * (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt() as f32;
                    });
                });
        }
        boundary
    }
}

/// Coarse map of the uniform and the empty space of a medium, for
/// skipping it: blocks of `BLOCK^3` cells ([`BlockGrid`]) where, out to
/// one cell beyond the block, the index is one constant, its gradient is
/// zero, the extinction is one constant per channel and nothing emits
/// (uniform blocks), and among them those where nothing absorbs or
/// scatters (empty blocks). Any trilinear sample taken within a cell of
/// such a block sees exactly those constants, so a ray there goes
/// straight, loses a known share per unit of length, and may be moved
/// without sampling at all. Neighbouring uniform blocks share their
/// margins, so a cube of them holds one index and one extinction.
#[derive(Clone, Debug)]
pub struct EmptySpace {
    blocks: BlockGrid,
    /// The block's uniform index, or NaN where the block is not uniform.
    n: Vec<f64>,
    /// The uniform block's extinction per channel.
    sigma: Vec<[f32; 3]>,
    /// Per uniform block, the largest `c` such that every block within
    /// Chebyshev distance `c` of it (a cube of `2c + 1` blocks a side) is
    /// uniform or outside the grid ([`Self::reach`]); 0 elsewhere.
    clear: Vec<u8>,
}

impl EmptySpace {
    /// The uniform and empty space of index channel `channel` of `medium`.
    pub fn new(medium: &Medium, channel: usize) -> Self {
        if !medium.has_voxel_fields() {
            return Self::unknown(&medium.geometry);
        }
        let idx = &medium.index[channel];
        Self::with_index(medium, |blocks, b| {
            let [i0, j0, k0] = blocks.first_voxel(b);
            let n0 = idx[[i0, j0, k0, 0]];
            blocks
                .all_around(b, |i, j, k| {
                    idx[[i, j, k, 0]] == n0 && (1..4).all(|c| idx[[i, j, k, c]] == 0.0)
                })
                .then_some(n0 as f64)
        })
    }

    /// The uniform and empty space of `medium` given `index(blocks, b)`,
    /// the one index light sees throughout block `b` and a cell around it
    /// (`None` where it is not one constant), and the medium's extinction.
    fn with_index(
        medium: &Medium,
        index: impl Fn(&BlockGrid, [usize; 3]) -> Option<f64> + Sync,
    ) -> Self {
        let blocks = BlockGrid::new(&medium.geometry);
        let ext = &medium.extinction;
        let mut n = vec![f64::NAN; blocks.len()];
        let mut sigma = vec![[0.0f32; 3]; blocks.len()];
        n.par_iter_mut()
            .zip(sigma.par_iter_mut())
            .enumerate()
            .for_each(|(flat, (out, sig))| {
                let b = blocks.coords(flat);
                let Some(n0) = index(&blocks, b) else {
                    return;
                };
                let [i0, j0, k0] = blocks.first_voxel(b);
                let s0 = [0, 1, 2].map(|c| ext[[i0, j0, k0, c]]);
                // The block and a margin of one cell around it.
                // (Emission does not matter to light crossing the block:
                // the light simulation transports what the lights send.)
                let uniform =
                    blocks.all_around(b, |i, j, k| (0..3).all(|c| ext[[i, j, k, c]] == s0[c]));
                if uniform {
                    *out = n0;
                    *sig = s0;
                }
            });
        let clear = clearance(&blocks, &n);
        Self {
            blocks,
            n,
            sigma,
            clear,
        }
    }

    /// No block known to be uniform: what a medium without voxel fields
    /// ([`Medium::has_voxel_fields`]) has, and what a light simulation with
    /// sharp interfaces (which goes by the regions themselves) needs.
    pub fn unknown(grid: &GridGeometry) -> Self {
        let blocks = BlockGrid::new(grid);
        let n = vec![f64::NAN; blocks.len()];
        Self {
            clear: clearance(&blocks, &n),
            sigma: vec![[0.0; 3]; blocks.len()],
            n,
            blocks,
        }
    }

    /// How far a straight line from `p` may run in any direction and stay
    /// within uniform blocks of the index and extinction at `p` ([`Self::uniform_at`]), world
    /// units; 0 where `p` is not in a uniform block. The distance from `p`
    /// to the faces of the cube of uniform blocks around its own (of one
    /// index and extinction: neighbouring uniform blocks share their
    /// margins). Outside the grid the index is the nearest edge cell's,
    /// which the cube holds, but nothing absorbs: the cube reaches past the
    /// grid's faces only where its blocks are empty.
    #[inline]
    pub fn reach(&self, p: DVec3) -> f64 {
        let Some((b, u)) = self.blocks.locate(p) else {
            return 0.0;
        };
        let flat = self.blocks.flat(b);
        if self.n[flat].is_nan() {
            return 0.0;
        }
        let c = self.clear[flat] as f64;
        let empty = self.sigma[flat] == [0.0; 3];
        let edge = 1.0 / self.blocks.inv_edge();
        (0..3)
            .map(|a| {
                let (mut lo, mut hi) = (b[a] as f64 - c, b[a] as f64 + c + 1.0);
                if !empty {
                    // The grid's faces, in blocks (a last block may be
                    // cut short; its cells end where the grid does).
                    lo = lo.max(0.0);
                    hi = hi.min(self.blocks.extent(a));
                }
                (u[a] - lo).min(hi - u[a]) * edge[a]
            })
            .fold(f64::INFINITY, f64::min)
    }

    /// The index and extinction per channel around `p` if `p` lies in a
    /// uniform block inside the grid, else `None`.
    #[inline(always)]
    pub fn uniform_at(&self, p: DVec3) -> Option<(f64, DVec3)> {
        let (b, _) = self.blocks.locate(p)?;
        let flat = self.blocks.flat(b);
        let n = self.n[flat];
        let s = self.sigma[flat];
        (!n.is_nan()).then(|| (n, DVec3::new(s[0] as f64, s[1] as f64, s[2] as f64)))
    }

    /// [`Self::reach`]'s table: per block, the cube of uniform blocks around
    /// it as its half-width `c` (0 where not uniform).
    pub fn clearance(&self) -> &[u8] {
        &self.clear
    }

    /// Its blocks.
    pub fn blocks(&self) -> &BlockGrid {
        &self.blocks
    }

    /// The uniform index around `p` if `p` lies in an empty block inside
    /// the grid, else `None`.
    #[inline(always)]
    pub fn index_at(&self, p: DVec3) -> Option<f64> {
        let (b, _) = self.blocks.locate(p)?;
        let flat = self.blocks.flat(b);
        let n = self.n[flat];
        (!n.is_nan() && self.sigma[flat] == [0.0; 3]).then_some(n)
    }

    /// Fraction of blocks that are empty.
    pub fn empty_fraction(&self) -> f64 {
        let empty = self.n.iter().zip(&self.sigma);
        empty
            .filter(|(x, s)| !x.is_nan() && **s == [0.0; 3])
            .count() as f64
            / self.n.len() as f64
    }
}

/// Per block, the largest `c` such that every block within Chebyshev
/// distance `c` is uniform (`n` not NaN) or outside the grid (where light
/// goes straight, in the index of the grid's edge); 0 for a block that is
/// not uniform. One less than the chessboard distance to the nearest block
/// that is not uniform, which two raster passes of the
/// 26-neighbour chamfer give exactly (Rosenfeld and Pfaltz, "Sequential
/// operations in digital picture processing", 1966,
/// doi:10.1145/321356.321357).
fn clearance(blocks: &BlockGrid, n: &[f64]) -> Vec<u8> {
    let [bx, by, bz] = blocks.dims.map(|d| d as i64);
    // Chessboard distance to the nearest block that is not uniform.
    let mut d: Vec<u16> = n
        .iter()
        .map(|x| if x.is_nan() { 0 } else { u16::MAX })
        .collect();
    let at = |i: i64, j: i64, k: i64| ((i * by + j) * bz + k) as usize;
    let pass = |d: &mut Vec<u16>, forward: bool| {
        let order: Box<dyn Iterator<Item = usize>> = if forward {
            Box::new(0..d.len())
        } else {
            Box::new((0..d.len()).rev())
        };
        for flat in order {
            if d[flat] == 0 {
                continue;
            }
            let [i, j, k] = blocks.coords(flat).map(|x| x as i64);
            let mut best = d[flat];
            for di in -1..=1i64 {
                for dj in -1..=1i64 {
                    for dk in -1..=1i64 {
                        // The half of the neighbourhood already visited.
                        let before = (di, dj, dk) < (0, 0, 0);
                        if (di, dj, dk) == (0, 0, 0) || before != forward {
                            continue;
                        }
                        let (a, b, c) = (i + di, j + dj, k + dk);
                        if a >= 0 && b >= 0 && c >= 0 && a < bx && b < by && c < bz {
                            best = best.min(d[at(a, b, c)].saturating_add(1));
                        }
                    }
                }
            }
            d[flat] = best;
        }
    };
    pass(&mut d, true);
    pass(&mut d, false);
    d.iter()
        .map(|&x| x.saturating_sub(1).min(u8::MAX as u16) as u8)
        .collect()
}

/// Trilinear sampling of one voxelized index channel and its stored gradient.
#[derive(Clone, Copy, Debug)]
pub struct VoxelField<'a> {
    data: &'a [f32],
    min: DVec3,
    inv_spacing: DVec3,
    /// Largest continuous voxel coordinate per axis (`dims - 1`).
    hi: DVec3,
    /// Largest lower-corner cell per axis (`dims - 2`, or 0 for one cell).
    max_cell: [usize; 3],
    /// Float strides per axis; 0 along an axis with a single cell.
    strides: [usize; 3],
}

impl<'a> VoxelField<'a> {
    fn new(data: &'a [f32], geometry: &GridGeometry) -> Self {
        let [nx, ny, nz] = geometry.dims;
        let dims = geometry.dims;
        let full = [ny * nz * 4, nz * 4, 4];
        assert_eq!(data.len(), nx * ny * nz * 4);
        Self {
            data,
            min: geometry.min,
            inv_spacing: 1.0 / geometry.spacing(),
            hi: DVec3::new(nx as f64, ny as f64, nz as f64) - 1.0,
            max_cell: dims.map(|d| d.saturating_sub(2)),
            strides: [0, 1, 2].map(|a| if dims[a] > 1 { full[a] } else { 0 }),
        }
    }
}

impl IndexField for VoxelField<'_> {
    #[inline(always)]
    fn sample(&self, p: DVec3) -> (f64, DVec3) {
        // Cell-centre convention: centres at integer voxel coordinates.
        // Clamping holds the edge value in the outer half cell; a NaN
        // position clamps to NaN and truncates to cell 0, never out of range.
        let u = ((p - self.min) * self.inv_spacing - 0.5).clamp(DVec3::ZERO, self.hi);
        // u >= 0, so truncation is floor (and avoids a libm call on targets
        // without SSE4.1).
        let i = (u.x as usize).min(self.max_cell[0]);
        let j = (u.y as usize).min(self.max_cell[1]);
        let k = (u.z as usize).min(self.max_cell[2]);
        let fx = (u.x - i as f64) as f32;
        let fy = (u.y - j as f64) as f32;
        let fz = (u.z - k as f64) as f32;
        let [ox, oy, oz] = self.strides;
        let base = i * ox + j * oy + k * oz;
        // One bounds check for all eight corners: the farthest is last.
        let cell = &self.data[base..base + ox + oy + oz + 4];
        let at = |o: usize| Vec4::from_slice(&cell[o..o + 4]);
        // a + (b - a) t, not glam's a (1 - t) + b t: equal corners then give
        // their value exactly, so a uniform region samples its own index.
        let lerp = |a: Vec4, b: Vec4, t: f32| a + (b - a) * t;
        let c00 = lerp(at(0), at(oz), fz);
        let c01 = lerp(at(oy), at(oy + oz), fz);
        let c10 = lerp(at(ox), at(ox + oz), fz);
        let c11 = lerp(at(ox + oy), at(ox + oy + oz), fz);
        let v = lerp(lerp(c00, c01, fy), lerp(c10, c11, fy), fx);
        let n = v.x as f64;
        // Stored: grad(n^2 / 2); grad n = grad(n^2 / 2) / n. One reciprocal
        // (which the ray step reuses for v / n) instead of three divisions.
        let inv = 1.0 / n;
        (n, DVec3::new(v.y as f64, v.z as f64, v.w as f64) * inv)
    }
}

/// Exact sampling of the scene's analytic index (no voxels, no smoothing):
/// the owning object's profile and its gradient. Object surfaces are true
/// discontinuities here and contribute no gradient, so this is meant for
/// smooth profiles (Luneburg, linear), to tell integrator error apart from
/// discretization error.
#[derive(Clone, Copy, Debug)]
pub struct AnalyticField<'a> {
    scene: &'a Scene,
    channel: usize,
}

impl<'a> AnalyticField<'a> {
    /// The exact field of `scene` for colour `channel` (0..3).
    pub fn new(scene: &'a Scene, channel: usize) -> Self {
        Self { scene, channel }
    }
}

impl IndexField for AnalyticField<'_> {
    #[inline]
    fn sample(&self, p: DVec3) -> (f64, DVec3) {
        self.scene.material_at(p).index.sample(p, self.channel)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn medium(text: &str) -> Medium {
        Medium::build(&Scene::parse(text, "test").unwrap()).unwrap()
    }

    #[test]
    fn supersampling_gives_fractional_coverage() {
        // Without smoothing, a plane through a quarter of cell i = 4 along x
        // gives that cell a quarter of the glass: n = 1 + 0.5 / 4.
        let m = medium(
            r#"
[grid]
resolution = [8, 4, 4]
min = [0, 0, 0]
max = [8, 4, 4]
smoothing = 0
supersample = 8
[[object]]
shape = { type = "half_space", point = [4.25, 0, 0], normal = [1, 0, 0] }
index = 1.5
extinction = [2, 4, 8]
"#,
        );
        let n = |i: usize| m.index[0][[i, 1, 1, 0]];
        assert_eq!(n(3), 1.5);
        assert_eq!(n(4), 1.125);
        assert_eq!(n(5), 1.0);
        assert_eq!(m.extinction[[4, 2, 2, 2]], 2.0);
        assert_eq!(m.extinction[[0, 0, 0, 1]], 4.0);
    }

    #[test]
    fn boundary_indicator_integrates_to_one_per_crossing() {
        let m = medium(
            r#"
[grid]
resolution = 64
min = [-1, -1, -1]
max = [1, 1, 1]
[[object]]
shape = { type = "sphere", center = [0.013, -0.021, 0.007], radius = 0.6 }
index = 1.5
"#,
        );
        // Along the x row through the centre: two crossings of the surface.
        let h = m.geometry.spacing().x as f32;
        let (j, k) = (31, 32);
        let total: f32 = (0..64).map(|i| m.boundary[[i, j, k]] * h).sum();
        assert!((total - 2.0).abs() < 0.03, "integral {total}");
        // Far from the surface it vanishes.
        assert_eq!(m.boundary[[32, 32, 32]], 0.0);
        assert_eq!(m.boundary[[0, 0, 0]], 0.0);
    }

    #[test]
    fn build_is_the_same_whatever_the_thread_count() {
        let scene = Scene::parse(
            r#"
[grid]
resolution = 24
min = [-1, -1, -1]
max = [1, 1, 1]
[[object]]
shape = { type = "torus", center = [0, 0, 0], major_radius = 0.5, minor_radius = 0.2, rotation = [20, 10, 0] }
index = 1.6
extinction = [1, 2, 3]
[[object]]
shape = { type = "sphere", center = [0.5, 0, 0], radius = 0.3 }
index = { type = "luneburg" }
priority = 1
"#,
            "t",
        )
        .unwrap();
        let with = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| Medium::build(&scene).unwrap())
        };
        let (a, b) = (with(1), with(3));
        assert_eq!(a.index, b.index);
        assert_eq!(a.boundary, b.boundary);
        assert_eq!(a.extinction, b.extinction);
    }

    #[test]
    fn rgb_fields_sample_trilinearly() {
        let m = medium(
            "[grid]\nresolution = [4, 1, 1]\nmin = [0, 0, 0]\nmax = [4, 1, 1]\nsmoothing = 0\n[[object]]\nshape = { type = \"box\", center = [3, 0.5, 0.5], size = [2, 2, 2] }\nindex = 1.5\nextinction = [2, 4, 6]\n",
        );
        // Centres at x = 0.5, 1.5, 2.5, 3.5; the box covers x > 2.
        let e = |x: f64| m.sample_rgb(&m.extinction, DVec3::new(x, 0.5, 0.5));
        assert_eq!(e(1.5), DVec3::ZERO);
        assert_eq!(e(2.0), DVec3::new(1.0, 2.0, 3.0));
        assert_eq!(e(3.9), DVec3::new(2.0, 4.0, 6.0));
    }

    #[test]
    fn empty_space_is_found_around_objects_only() {
        let m = medium(
            "[grid]\nresolution = 32\nmin = [-1, -1, -1]\nmax = [1, 1, 1]\n[[object]]\nshape = { type = \"sphere\", center = [0, 0, 0], radius = 0.3 }\nindex = 1.5\n",
        );
        let e = EmptySpace::new(&m, 0);
        assert_eq!(e.index_at(DVec3::new(0.9, 0.9, 0.9)), Some(1.0));
        assert_eq!(e.index_at(DVec3::ZERO), None);
        assert_eq!(e.index_at(DVec3::new(0.32, 0.0, 0.0)), None);
        assert_eq!(e.index_at(DVec3::new(1.5, 0.0, 0.0)), None);
        // Wherever it claims emptiness, sampling agrees exactly.
        let f = m.field(0);
        for i in 0..4000 {
            let t = |k: u32| ((i * 7919 + k * 104_729) % 1000) as f64 / 500.0 - 1.0;
            let p = DVec3::new(t(1), t(2), t(3));
            if let Some(n) = e.index_at(p) {
                let (fn_, g) = f.sample(p);
                assert_eq!((fn_, g), (n, DVec3::ZERO), "at {p}");
            }
        }
        // Every block whose cells (and margin) lie beyond the smoothed
        // surface (radius + 3 sigma + supersampling + margin < 6 cells) is
        // found empty.
        let h = m.geometry.voxel_size();
        let blk = crate::blocks::BLOCK as f64 * h;
        for (bi, bj, bk) in
            (0..8).flat_map(|i| (0..8).flat_map(move |j| (0..8).map(move |k| (i, j, k))))
        {
            let c = m.geometry.min + (DVec3::new(bi as f64, bj as f64, bk as f64) + 0.5) * blk;
            if c.length() - 0.5 * blk * 3f64.sqrt() > 0.3 + 6.0 * h {
                assert!(e.index_at(c).is_some(), "block at {c} should be empty");
            }
        }
        assert!(e.empty_fraction() > 0.5, "{}", e.empty_fraction());
    }

    #[test]
    fn clearance_is_the_chessboard_distance_less_one() {
        // Random blocked blocks on an uneven block grid, against the
        // definition by brute force: the largest cube around each of
        // blocks empty or outside the grid.
        let grid = GridGeometry::new([64, 48, 70], DVec3::ZERO, DVec3::new(6.4, 4.8, 7.0));
        let blocks = BlockGrid::new(&grid);
        let [bx, by, bz] = blocks.dims.map(|d| d as i64);
        let mut state = 12345u64;
        let n: Vec<f64> = (0..blocks.len())
            .map(|_| {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                if (state >> 33).is_multiple_of(97) {
                    f64::NAN
                } else {
                    1.0
                }
            })
            .collect();
        let clear = clearance(&blocks, &n);
        let empty = |i: i64, j: i64, k: i64| {
            let inside = i >= 0 && j >= 0 && k >= 0 && i < bx && j < by && k < bz;
            !inside || !n[blocks.flat([i as usize, j as usize, k as usize])].is_nan()
        };
        let mut largest = 0;
        for (flat, &got) in clear.iter().enumerate() {
            let [i, j, k] = blocks.coords(flat).map(|x| x as i64);
            let want = if !empty(i, j, k) {
                0
            } else {
                let cube_empty = |c: i64| {
                    (-c..=c).all(|a| (-c..=c).all(|b| (-c..=c).all(|d| empty(i + a, j + b, k + d))))
                };
                let mut c = 0;
                while c < 255 && cube_empty(c + 1) {
                    c += 1;
                }
                c
            };
            assert_eq!(got as i64, want, "block {i} {j} {k}");
            largest = largest.max(want);
        }
        assert!(largest >= 2, "the test should reach past neighbours");
    }

    #[test]
    fn a_straight_run_within_reach_stays_in_empty_space() {
        let m = medium(
            "[grid]\nresolution = 48\nmin = [-1, -1, -1]\nmax = [1, 1, 1]\n[[object]]\nshape = { type = \"box\", center = [0.2, -0.1, 0], size = [0.3, 0.5, 0.4], rotation = [10, 20, 30] }\nindex = 1.5\n",
        );
        let e = EmptySpace::new(&m, 0);
        let mut some = 0;
        for i in 0..3000u32 {
            let t = |k: u32| ((i * 7919 + k * 104_729) % 1000) as f64 / 500.0 - 1.0;
            let p = DVec3::new(t(1), t(2), t(3));
            let d = DVec3::new(t(4), t(5), t(6)).normalize_or_zero();
            let r = e.reach(p);
            if e.index_at(p).is_none() {
                assert_eq!(r, 0.0);
                continue;
            }
            if r > 4.0 * m.geometry.voxel_size() {
                some += 1;
            }
            for s in 0..=64 {
                let q = p + d * (r * s as f64 / 64.0 * (1.0 - 1e-12));
                if m.geometry.contains(q) {
                    assert_eq!(e.index_at(q), Some(1.0), "{p} + {d} * {r}: {q}");
                } else {
                    // Outside, a sample clamps to the nearest edge cell.
                    let g = &m.geometry;
                    let edge = q.clamp(g.min, g.max - (g.max - g.min) * 1e-12);
                    assert_eq!(e.index_at(edge), Some(1.0), "{q} beyond {edge}");
                }
            }
        }
        assert!(some > 100, "{some} long runs");
    }

    #[test]
    fn uniform_absorbing_space_holds_one_index_and_extinction() {
        // An absorbing box with a constant index and extinction, reaching
        // the grid's faces on two sides, in empty space.
        let m = medium(
            "[grid]\nresolution = 48\nmin = [-1, -1, -1]\nmax = [1, 1, 1]\n[[object]]\nshape = { type = \"box\", center = [0.4, 0.0, 0.0], size = [1.6, 1.6, 1.6] }\nindex = 1.5\nextinction = [2.0, 1.0, 0.5]\n",
        );
        let e = EmptySpace::new(&m, 0);
        let f = m.field(0);
        let sigma = DVec3::new(2.0f32 as f64, 1.0, 0.5);
        let (mut absorbing, mut long) = (0, 0);
        let mut rng = eikon_rng::SplitMix64::new(7);
        for _ in 0..4000 {
            let p = DVec3::from(std::array::from_fn(|_| rng.uniform(-1.0, 1.0)));
            let d = DVec3::from(rng.direction());
            let Some((n, s)) = e.uniform_at(p) else {
                assert_eq!(e.index_at(p), None);
                assert_eq!(e.reach(p), 0.0);
                continue;
            };
            if s == DVec3::ZERO {
                assert_eq!(e.index_at(p), Some(n));
                continue;
            }
            // Inside the box's core: its own index and extinction, and
            // not empty.
            assert_eq!((n, s), (1.5, sigma), "at {p}");
            assert_eq!(e.index_at(p), None);
            absorbing += 1;
            let r = e.reach(p);
            if r > 2.0 * m.geometry.voxel_size() {
                long += 1;
            }
            // Along any line within reach: still inside the grid, every
            // sample the same index (no gradient) and extinction.
            for k in 0..=64 {
                let q = p + d * (r * k as f64 / 64.0 * (1.0 - 1e-12));
                assert!(m.geometry.contains(q), "{p} + {d} * {r} leaves the grid");
                assert_eq!(e.uniform_at(q), Some((n, s)), "{q}");
                assert_eq!(f.sample(q), (1.5, DVec3::ZERO), "{q}");
                // Trilinear weights of equal values, to their rounding.
                let got = m.sample_rgb(&m.extinction, q);
                assert!((got - sigma).abs().max_element() < 1e-15, "{q}: {got}");
            }
        }
        assert!(
            absorbing > 200 && long > 20,
            "{absorbing} in the core, {long} long"
        );
    }

    #[test]
    fn uniform_medium_samples_exactly() {
        let m = medium(
            "[grid]\nresolution = 12\nmin = [0, 0, 0]\nmax = [1, 1, 1]\n[ambient]\nindex = 1.33\n",
        );
        let f = m.field(0);
        for p in [
            DVec3::splat(0.5),
            DVec3::new(0.01, 0.77, 0.999),
            DVec3::new(2.0, -1.0, 0.5),
        ] {
            assert_eq!(f.sample(p), (1.33f32 as f64, DVec3::ZERO));
        }
    }
}
