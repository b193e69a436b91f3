//! Separable Gaussian smoothing and central-difference gradients.

use ndarray::{Array3, ArrayView3, ArrayViewMut1, Axis, Zip};

/// Radius in cells of the truncated kernel for `sigma` (in cells).
pub fn kernel_radius(sigma: f64) -> usize {
    if sigma > 0.0 {
        (3.0 * sigma).ceil() as usize
    } else {
        0
    }
}

/// Normalized weights `w[0..=r]` of the symmetric kernel.
fn kernel(sigma: f64) -> Vec<f64> {
    let r = kernel_radius(sigma);
    let mut w: Vec<f64> = (0..=r)
        .map(|k| (-((k * k) as f64) / (2.0 * sigma * sigma)).exp())
        .collect();
    let total = w[0] + 2.0 * w[1..].iter().sum::<f64>();
    w.iter_mut().for_each(|x| *x /= total);
    w
}

fn smooth_lane(mut lane: ArrayViewMut1<f32>, w: &[f64], scratch: &mut Vec<f32>) {
    let len = lane.len() as isize;
    scratch.clear();
    scratch.extend(lane.iter());
    let r = w.len() as isize - 1;
    for i in 0..len {
        // Symmetric pairs summed in a fixed order: equal inputs give equal
        // outputs bit for bit, so a homogeneous region stays exactly flat
        // and its gradient exactly zero.
        let mut acc = w[0] * scratch[i as usize] as f64;
        for k in 1..=r {
            let a = scratch[(i - k).clamp(0, len - 1) as usize] as f64;
            let b = scratch[(i + k).clamp(0, len - 1) as usize] as f64;
            acc += w[k as usize] * (a + b);
        }
        lane[i as usize] = acc as f32;
    }
}

/// Smooth `a` in place with a Gaussian of `sigma` cells along each axis.
/// Edges are clamped; callers pad the array so the clamped band is cropped.
pub fn gaussian(a: &mut Array3<f32>, sigma: f64) {
    if sigma <= 0.0 {
        return;
    }
    let w = kernel(sigma);
    for axis in 0..3 {
        Zip::from(a.lanes_mut(Axis(axis))).par_for_each(|lane| {
            let mut scratch = Vec::with_capacity(lane.len());
            smooth_lane(lane, &w, &mut scratch);
        });
    }
}

/// Central-difference gradient (per world unit, with cell sizes `h`) of `a`
/// at cell `(i, j, k)`, which must have a neighbour on both sides.
#[inline]
pub fn central_gradient(a: &ArrayView3<f32>, i: usize, j: usize, k: usize, h: [f64; 3]) -> [f64; 3] {
    [
        (a[[i + 1, j, k]] as f64 - a[[i - 1, j, k]] as f64) / (2.0 * h[0]),
        (a[[i, j + 1, k]] as f64 - a[[i, j - 1, k]] as f64) / (2.0 * h[1]),
        (a[[i, j, k + 1]] as f64 - a[[i, j, k - 1]] as f64) / (2.0 * h[2]),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kernel_is_normalized_and_linear_fields_survive() {
        let w = kernel(0.75);
        assert!((w[0] + 2.0 * w[1..].iter().sum::<f64>() - 1.0).abs() < 1e-12);
        let mut a = Array3::from_shape_fn((20, 20, 20), |(i, j, k)| {
            1.0 + 0.01 * i as f32 + 0.02 * j as f32 - 0.005 * k as f32
        });
        let orig = a.clone();
        gaussian(&mut a, 1.0);
        // Away from the clamped edges a symmetric kernel leaves a linear field.
        for i in 4..16 {
            for j in 4..16 {
                for k in 4..16 {
                    assert!((a[[i, j, k]] - orig[[i, j, k]]).abs() < 2e-6);
                }
            }
        }
        let mut c = Array3::from_elem((9, 9, 9), 1.33f32);
        gaussian(&mut c, 0.75);
        assert!(c.iter().all(|&x| x == c[[0, 0, 0]]));
    }
}
