//! A float grid as a solid: inside where the trilinearly interpolated value
//! exceeds a threshold, with a conservative distance bound for the
//! voxelizer (which supersamples only the cells a surface may cross).

use super::FloatVolume;
use glam::DVec3;
use rayon::prelude::*;
use std::sync::Arc;

/// The solid `{ p : volume.sample(p) > threshold }`.
///
/// The distance bound comes from a Euclidean distance transform over the
/// grid's voxels: `S` is the set of voxels with a 26-neighbour on the other
/// side of the threshold. Every point of the surface lies in a cell whose
/// eight corner voxels straddle the threshold, all of which are in `S`, so it
/// is within half a voxel diagonal of `S`; the bound at `p` is the distance
/// from `p` to `S` (through the nearest voxel centre) less that margin.
#[derive(Clone)]
pub struct VdbSolid {
    volume: Arc<FloatVolume>,
    threshold: f64,
    /// World distance from each voxel of the dense box to `S`.
    edt: Vec<f32>,
    /// Half the diagonal of a voxel, world units.
    margin: f64,
    /// World box of the dense box's voxel centres.
    centres: (DVec3, DVec3),
    aabb: Option<(DVec3, DVec3)>,
    /// Voxels above the threshold.
    inside_voxels: u64,
}

impl std::fmt::Debug for VdbSolid {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VdbSolid")
            .field("volume", &self.volume)
            .field("threshold", &self.threshold)
            .field("aabb", &self.aabb)
            .finish_non_exhaustive()
    }
}

/// World box spanned by index box `[lo, hi]` of `volume`'s transform.
fn world_box(volume: &FloatVolume, lo: DVec3, hi: DVec3) -> (DVec3, DVec3) {
    let a = volume.transform.index_to_world(lo);
    let b = volume.transform.index_to_world(hi);
    (a.min(b), a.max(b))
}

impl VdbSolid {
    /// The solid where `volume` exceeds `threshold`.
    pub fn new(volume: Arc<FloatVolume>, threshold: f64) -> Self {
        let dims = volume.dims();
        let n = dims.iter().product::<usize>();
        let side: Vec<bool> = volume.voxels().map(|(_, v)| v as f64 > threshold).collect();
        let inside_voxels = side.iter().filter(|&&s| s).count() as u64;
        let flat = |i: usize, j: usize, k: usize| (i * dims[1] + j) * dims[2] + k;
        // Squared distance: 0 on S, infinite elsewhere.
        let mut d2: Vec<f64> = (0..n)
            .into_par_iter()
            .map(|m| {
                let (i, j, k) = (
                    m / (dims[1] * dims[2]),
                    (m / dims[2]) % dims[1],
                    m % dims[2],
                );
                let s = side[m];
                for di in i.saturating_sub(1)..(i + 2).min(dims[0]) {
                    for dj in j.saturating_sub(1)..(j + 2).min(dims[1]) {
                        for dk in k.saturating_sub(1)..(k + 2).min(dims[2]) {
                            if side[flat(di, dj, dk)] != s {
                                return 0.0;
                            }
                        }
                    }
                }
                f64::INFINITY
            })
            .collect();
        let h = volume.transform.voxel_size.abs();
        // Separable exact transform (Felzenszwalb & Huttenlocher), one axis
        // at a time.
        let strides = [dims[1] * dims[2], dims[2], 1];
        for axis in 0..3 {
            let len = dims[axis];
            if len == 0 {
                break;
            }
            // First voxel of every line along `axis`: coordinate 0 there.
            let stride = strides[axis];
            let lines: Vec<usize> = (0..n / len)
                .map(|r| (r / stride) * stride * len + r % stride)
                .collect();
            let results: Vec<(usize, Vec<f64>)> = lines
                .par_iter()
                .map(|&start| {
                    let f: Vec<f64> = (0..len).map(|q| d2[start + q * strides[axis]]).collect();
                    (start, edt_line(&f, h[axis]))
                })
                .collect();
            for (start, line) in results {
                for (q, v) in line.into_iter().enumerate() {
                    d2[start + q * strides[axis]] = v;
                }
            }
        }
        let edt = d2.into_iter().map(|v| v.sqrt() as f32).collect();
        let o = volume.origin();
        let lo = DVec3::new(o[0] as f64, o[1] as f64, o[2] as f64);
        let hi = lo + DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64) - 1.0;
        let centres = world_box(&volume, lo, hi);
        let aabb = if volume.background as f64 > threshold {
            None // inside everywhere far away: unbounded
        } else {
            let mut b: Option<(DVec3, DVec3)> = None;
            for (ijk, v) in volume.voxels() {
                if v as f64 > threshold {
                    let p = DVec3::new(ijk[0] as f64, ijk[1] as f64, ijk[2] as f64);
                    let e = b.get_or_insert((p, p));
                    e.0 = e.0.min(p);
                    e.1 = e.1.max(p);
                }
            }
            // The interpolant exceeds the threshold only within a voxel of
            // a voxel that does.
            Some(match b {
                Some((a, c)) => world_box(&volume, a - 1.0, c + 1.0),
                None => (volume.transform.translation, volume.transform.translation),
            })
        };
        Self {
            margin: 0.5 * h.length(),
            volume,
            threshold,
            edt,
            centres,
            aabb,
            inside_voxels,
        }
    }

    /// The grid.
    pub fn volume(&self) -> &Arc<FloatVolume> {
        &self.volume
    }

    /// Inside where the grid exceeds this.
    pub fn threshold(&self) -> f64 {
        self.threshold
    }

    /// Number of voxels above the threshold (0: the solid is empty, unless
    /// the background exceeds the threshold).
    pub fn inside_voxels(&self) -> u64 {
        self.inside_voxels
    }

    /// Whether `p` is inside.
    pub fn contains(&self, p: DVec3) -> bool {
        self.volume.sample(p) > self.threshold
    }

    /// Signed distance bound: negative inside, positive outside, never
    /// larger in magnitude than the distance to the surface. Where the
    /// bound is zero (within the margin of the surface) it is the smallest
    /// positive double, signed: the sign alone still tells the side, as
    /// root finding on a path that crosses the surface needs (a zero
    /// outside read as the far side cut a curved step at its start).
    pub fn distance(&self, p: DVec3) -> f64 {
        let inside = self.contains(p);
        let bound = if self.edt.is_empty() {
            f64::INFINITY
        } else {
            let dims = self.volume.dims();
            let o = self.volume.origin();
            let u = self.volume.transform.world_to_index(p);
            let mut c = [0usize; 3];
            for a in 0..3 {
                let l = (u[a].round() - o[a] as f64).clamp(0.0, dims[a] as f64 - 1.0);
                c[a] = if l.is_nan() { 0 } else { l as usize };
            }
            let centre = self.volume.transform.index_to_world(DVec3::new(
                (o[0] + c[0] as i32) as f64,
                (o[1] + c[1] as i32) as f64,
                (o[2] + c[2] as i32) as f64,
            ));
            let d = self.edt[(c[0] * dims[1] + c[1]) * dims[2] + c[2]] as f64;
            let outside_box = (self.centres.0 - p)
                .max(p - self.centres.1)
                .max(DVec3::ZERO)
                .length();
            // f32 storage of the transform: keep a little slack.
            let through_centre = (d - (p - centre).length() - self.margin) * (1.0 - 1e-6);
            outside_box.max(through_centre).max(0.0)
        };
        if inside {
            -bound.max(f64::MIN_POSITIVE)
        } else {
            bound.max(f64::MIN_POSITIVE)
        }
    }

    /// World-space bounding box of the solid, or `None` when it is
    /// unbounded (the background exceeds the threshold).
    pub fn aabb(&self) -> Option<(DVec3, DVec3)> {
        self.aabb
    }
}

/// Squared distance transform of one line: `min_p h^2 (q - p)^2 + f(p)`.
fn edt_line(f: &[f64], h: f64) -> Vec<f64> {
    let n = f.len();
    let mut out = vec![f64::INFINITY; n];
    let mut v: Vec<usize> = Vec::with_capacity(n);
    let mut z: Vec<f64> = Vec::with_capacity(n + 1);
    let x = |q: usize| q as f64 * h;
    for q in 0..n {
        if !f[q].is_finite() {
            continue;
        }
        loop {
            match v.last() {
                None => {
                    v.push(q);
                    z.clear();
                    z.push(f64::NEG_INFINITY);
                    break;
                }
                Some(&p) => {
                    let s = ((f[q] + x(q) * x(q)) - (f[p] + x(p) * x(p))) / (2.0 * (x(q) - x(p)));
                    if s <= *z.last().expect("one boundary per parabola") {
                        v.pop();
                        z.pop();
                    } else {
                        v.push(q);
                        z.push(s);
                        break;
                    }
                }
            }
        }
    }
    if v.is_empty() {
        return out;
    }
    let mut k = 0;
    for (q, o) in out.iter_mut().enumerate() {
        while k + 1 < v.len() && z[k + 1] < x(q) {
            k += 1;
        }
        let p = v[k];
        *o = (x(q) - x(p)) * (x(q) - x(p)) + f[p];
    }
    out
}

#[cfg(test)]
mod tests {
    use super::edt_line;

    #[test]
    fn line_transform_is_exact() {
        let inf = f64::INFINITY;
        let f = [inf, 0.0, inf, inf, inf, 0.0, inf];
        let d = edt_line(&f, 0.5);
        let want = [0.25, 0.0, 0.25, 1.0, 0.25, 0.0, 0.25];
        for (a, b) in d.iter().zip(want) {
            assert!((a - b).abs() < 1e-12, "{d:?}");
        }
        assert!(edt_line(&[inf, inf], 1.0).iter().all(|v| v.is_infinite()));
    }
}
