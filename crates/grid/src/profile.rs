//! The profile of a solid of revolution: a closed polygon of (radius,
//! height) points, with its edges filed by height.
//!
//! Whether a point lies inside, and where a short segment first meets the
//! surface, depend only on the edges whose heights reach the point's (or
//! the segment's): a light step is half a voxel, so of a wine glass's
//! fifteen edges one or two. The edges are filed in bands of equal height
//! once, so that those queries read only the bands they touch. The answers
//! are the ones a pass over every edge gives, bit for bit.

use glam::DVec2;
use std::ops::Deref;

/// A closed (radius, height) polygon with its edges filed by height.
#[derive(Clone, Debug)]
pub struct Profile {
    points: Vec<DVec2>,
    /// +1 for a counter-clockwise polygon, -1 for clockwise.
    orientation: f64,
    /// Edge `i`'s two ends (point `i` and the next), and the band of its
    /// lower end.
    ends: Vec<(DVec2, DVec2)>,
    first_band: Vec<u32>,
    /// The lowest height and `1 / ` the bands' height.
    y0: f64,
    per_band: f64,
    /// Band `b`'s edges are `edges[starts[b]..starts[b + 1]]`, by index.
    starts: Vec<u32>,
    edges: Vec<u32>,
}

impl Profile {
    /// File the edges of the closed polygon `points` (edge `i` runs from
    /// point `i` to point `i + 1`, the last back to the first).
    pub fn new(points: Vec<DVec2>) -> Self {
        let n = points.len();
        let mut area2 = 0.0;
        for i in 0..n {
            let (p, q) = (points[i], points[(i + 1) % n]);
            area2 += p.x * q.y - q.x * p.y;
        }
        let orientation = if area2 >= 0.0 { 1.0 } else { -1.0 };
        let (y0, y1) = points
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
                (a.min(p.y), b.max(p.y))
            });
        // About one band per edge: an edge then shares its band with a few
        // others at most.
        let bands = n.clamp(1, 256);
        let per_band = if y1 > y0 && (y1 - y0).is_finite() {
            bands as f64 / (y1 - y0)
        } else {
            1.0
        };
        let ends: Vec<(DVec2, DVec2)> = (0..n).map(|i| (points[i], points[(i + 1) % n])).collect();
        let mut profile = Self {
            points,
            orientation,
            ends,
            first_band: Vec::with_capacity(n),
            y0: if y0.is_finite() { y0 } else { 0.0 },
            per_band,
            starts: vec![0; bands + 1],
            edges: Vec::new(),
        };
        let mut filed: Vec<Vec<u32>> = vec![Vec::new(); bands];
        for i in 0..n {
            let (a, b) = profile.edge(i);
            let (lo, hi) = (profile.band_of(a.y.min(b.y)), profile.band_of(a.y.max(b.y)));
            profile.first_band.push(lo as u32);
            for list in &mut filed[lo..=hi] {
                list.push(i as u32);
            }
        }
        for (b, list) in filed.iter().enumerate() {
            profile.edges.extend_from_slice(list);
            profile.starts[b + 1] = profile.edges.len() as u32;
        }
        profile
    }

    /// The polygon's points.
    pub fn points(&self) -> &[DVec2] {
        &self.points
    }

    /// +1 when the polygon runs counter-clockwise in the (radius, height)
    /// plane, -1 when clockwise.
    pub fn orientation(&self) -> f64 {
        self.orientation
    }

    /// Edge `i`: its two ends.
    #[inline]
    pub fn edge(&self, i: usize) -> (DVec2, DVec2) {
        self.ends[i]
    }

    /// The band of height `y` (the first or last for heights beyond). A
    /// height's band never decreases as the height grows, rounding
    /// included, which is what makes the filing exact.
    #[inline]
    fn band_of(&self, y: f64) -> usize {
        let last = self.starts.len() - 2;
        let b = (y - self.y0) * self.per_band;
        if b.is_nan() || b <= 0.0 {
            0
        } else if b >= last as f64 {
            last
        } else {
            b as usize // truncation: the floor of a positive number
        }
    }

    /// The indices of the edges whose heights may reach `y` (every edge
    /// that does, among a few that do not).
    #[inline]
    pub fn edges_at(&self, y: f64) -> &[u32] {
        let b = self.band_of(y);
        &self.edges[self.starts[b] as usize..self.starts[b + 1] as usize]
    }

    /// Call `f` once for each edge whose heights may reach into `[lo, hi]`
    /// (every edge that does), in no set order. NaN bounds visit every
    /// edge.
    #[inline]
    pub fn for_edges_within(&self, lo: f64, hi: f64, mut f: impl FnMut(usize)) {
        let (b0, b1) = if lo <= hi {
            (self.band_of(lo), self.band_of(hi))
        } else {
            (0, self.starts.len() - 2)
        };
        for b in b0..=b1 {
            for &i in &self.edges[self.starts[b] as usize..self.starts[b + 1] as usize] {
                // An edge in several bands is visited in the first of them
                // that the range reaches.
                if self.first_band[i as usize].max(b0 as u32) == b as u32 {
                    f(i as usize);
                }
            }
        }
    }
}

impl Deref for Profile {
    type Target = [DVec2];

    fn deref(&self) -> &[DVec2] {
        &self.points
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn glass() -> Profile {
        Profile::new(
            [
                (0.0, 0.0),
                (0.3, 0.0),
                (0.3, 0.025),
                (0.06, 0.05),
                (0.04, 0.1),
                (0.04, 0.5),
                (0.12, 0.56),
                (0.25, 0.7),
                (0.29, 0.9),
                (0.27, 1.3),
                (0.245, 1.3),
                (0.264, 0.9),
                (0.224, 0.714),
                (0.11, 0.59),
                (0.0, 0.575),
            ]
            .map(|(x, y)| DVec2::new(x, y))
            .to_vec(),
        )
    }

    /// Every edge whose heights reach `y` is filed where `y` is, at heights
    /// on the vertices, just beside them and between.
    #[test]
    fn every_edge_reaching_a_height_is_filed_there() {
        let p = glass();
        let mut heights: Vec<f64> = p.iter().map(|q| q.y).collect();
        for &y in heights.clone().iter() {
            heights.extend([y - 1e-12, y + 1e-12, y.next_up(), y.next_down()]);
        }
        heights.extend((0..=1000).map(|k| -0.1 + 1.5 * k as f64 / 1000.0));
        for y in heights {
            for i in 0..p.len() {
                let (a, b) = p.edge(i);
                if y >= a.y.min(b.y) && y <= a.y.max(b.y) {
                    assert!(p.edges_at(y).contains(&(i as u32)), "y {y}: edge {i}");
                }
            }
        }
    }

    /// A height range visits each edge reaching into it exactly once.
    #[test]
    fn a_height_range_visits_each_edge_reaching_it_once() {
        let p = glass();
        let mut seen = vec![0; p.len()];
        for k in 0..400 {
            let lo = -0.2 + 1.6 * (k as f64 * 0.618_034).fract();
            let hi = lo + 0.4 * (k as f64 * 0.414_214).fract();
            seen.iter_mut().for_each(|s| *s = 0);
            p.for_edges_within(lo, hi, |i| seen[i] += 1);
            for (i, &s) in seen.iter().enumerate() {
                let (a, b) = p.edge(i);
                let reaches = a.y.max(b.y) >= lo && a.y.min(b.y) <= hi;
                assert!(s <= 1, "[{lo}, {hi}]: edge {i} visited {s} times");
                assert!(!reaches || s == 1, "[{lo}, {hi}]: edge {i} missed");
            }
        }
        seen.iter_mut().for_each(|s| *s = 0);
        p.for_edges_within(f64::NAN, f64::NAN, |i| seen[i] += 1);
        assert!(seen.iter().all(|&s| s == 1));
    }

    /// The glass's outline runs out along the foot's underside, up the
    /// outside and back down the inside: counter-clockwise.
    #[test]
    fn orientation_follows_the_winding() {
        let p = glass();
        assert_eq!(p.orientation(), 1.0);
        let reversed = Profile::new(p.iter().rev().copied().collect());
        assert_eq!(reversed.orientation(), -1.0);
    }
}
