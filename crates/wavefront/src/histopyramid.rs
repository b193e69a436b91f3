//! HistoPyramid stream compaction and expansion (Ziegler et al. 2006, as
//! extended in [Ihrke07 sec 5.2.3]).
//!
//! Every input entry (a wavefront patch) asks for 0 (eliminate), 1
//! (retain) or 4 (tessellate) slots in the next list. The pyramid's base
//! holds those counts; each level above sums groups of four, so the top
//! holds the length of the new list. Output slot `k` then finds its source
//! by one top-down walk: at each level it steps into the child whose
//! running sum covers `k`, subtracting the sums it skipped. At the base,
//! what is left of `k` says which of the source's slots this is: for a
//! tessellated patch, which quarter.
//!
//! Both the build (level by level) and the walks (slot by slot) are
//! data-parallel with no shared writes, which is what makes the algorithm
//! a GPU kernel; the CPU version here runs the same steps with rayon and
//! reuses its buffers from one build to the next.

use eikon_shader::{nothing, Module};
use rayon::prelude::*;

/// The WGSL of the pyramid, the one the GPU simulator runs: the layout,
/// one reduction step, the walk ([`HistoPyramid::locate`]) and the rank
/// of an entry, over the kernel's `pyramid` array.
pub static WGSL: Module = Module {
    name: "histopyramid",
    requires: &[],
    declarations: nothing,
    text: include_str!("histopyramid.wgsl"),
};

/// Work items below which a level is reduced serially.
const PARALLEL_MIN: usize = 1 << 14;

/// A HistoPyramid over per-entry output counts.
#[derive(Clone, Debug, Default)]
pub struct HistoPyramid {
    /// `levels[0]` holds the counts; `levels[l + 1][j]` sums
    /// `levels[l][4j .. 4j + 4]`; the last level has one entry.
    levels: Vec<Vec<u32>>,
}

impl HistoPyramid {
    /// An empty pyramid; [`HistoPyramid::build`] fills it.
    pub fn new() -> Self {
        Self::default()
    }

    /// Build the pyramid over `counts` (each entry's number of output
    /// slots). Buffers from earlier builds are reused.
    pub fn build(&mut self, counts: &[u8]) {
        let mut len = counts.len();
        let mut depth = 1;
        while len > 1 {
            len = len.div_ceil(4);
            depth += 1;
        }
        self.levels.resize_with(depth, Vec::new);
        let base = &mut self.levels[0];
        base.clear();
        base.resize(counts.len().max(1), 0);
        if counts.len() >= PARALLEL_MIN {
            base.par_iter_mut()
                .zip(counts.par_iter())
                .for_each(|(b, &c)| *b = c as u32);
        } else {
            base.iter_mut()
                .zip(counts)
                .for_each(|(b, &c)| *b = c as u32);
        }
        for l in 1..depth {
            let (below, above) = self.levels.split_at_mut(l);
            let src = &below[l - 1];
            let dst = &mut above[0];
            dst.clear();
            dst.resize(src.len().div_ceil(4), 0);
            let reduce = |(j, d): (usize, &mut u32)| {
                *d = src[4 * j..(4 * j + 4).min(src.len())].iter().sum();
            };
            if dst.len() >= PARALLEL_MIN {
                dst.par_iter_mut().enumerate().for_each(reduce);
            } else {
                dst.iter_mut().enumerate().for_each(reduce);
            }
        }
    }

    /// Length of the output list: the sum of all counts.
    pub fn total(&self) -> usize {
        self.levels.last().map_or(0, |top| top[0] as usize)
    }

    /// Source entry of output slot `k` (< [`Self::total`]) and which of its
    /// slots `k` is (0 for a retained entry, 0..4 for a tessellated one).
    #[inline]
    pub fn locate(&self, k: usize) -> (usize, u32) {
        debug_assert!(k < self.total());
        let mut rest = k as u32;
        let mut node = 0usize;
        for level in self.levels[..self.levels.len() - 1].iter().rev() {
            let first = 4 * node;
            let mut child = first;
            // At most three skips: the walk's choice among four children.
            for &c in &level[first..(first + 3).min(level.len() - 1)] {
                if rest < c {
                    break;
                }
                rest -= c;
                child += 1;
            }
            node = child;
        }
        (node, rest)
    }

    /// Walk every output slot: `source[k]` and `part[k]` receive
    /// [`Self::locate`]`(k)`. The vectors are resized, reusing their memory.
    pub fn expand_into(&self, source: &mut Vec<u32>, part: &mut Vec<u8>) {
        let n = self.total();
        source.clear();
        source.resize(n, 0);
        part.clear();
        part.resize(n, 0);
        let walk = |(k, (s, p)): (usize, (&mut u32, &mut u8))| {
            let (i, q) = self.locate(k);
            *s = i as u32;
            *p = q as u8;
        };
        if n >= PARALLEL_MIN {
            source
                .par_iter_mut()
                .zip(part.par_iter_mut())
                .enumerate()
                .for_each(walk);
        } else {
            source
                .iter_mut()
                .zip(part.iter_mut())
                .enumerate()
                .for_each(walk);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The plain prefix-sum answer the pyramid must reproduce.
    fn reference(counts: &[u8]) -> (Vec<u32>, Vec<u8>) {
        let mut src = Vec::new();
        let mut part = Vec::new();
        for (i, &c) in counts.iter().enumerate() {
            for q in 0..c {
                src.push(i as u32);
                part.push(q);
            }
        }
        (src, part)
    }

    /// Deterministic pseudo-random counts from {0, 1, 4}.
    fn random_counts(n: usize, seed: u64) -> Vec<u8> {
        let mut s = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (0..n)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                [0, 1, 4][(s % 3) as usize]
            })
            .collect()
    }

    fn check(counts: &[u8], hp: &mut HistoPyramid) {
        hp.build(counts);
        let (want_src, want_part) = reference(counts);
        assert_eq!(hp.total(), want_src.len(), "n = {}", counts.len());
        let (mut src, mut part) = (Vec::new(), Vec::new());
        hp.expand_into(&mut src, &mut part);
        assert_eq!(src, want_src, "n = {}", counts.len());
        assert_eq!(part, want_part, "n = {}", counts.len());
    }

    #[test]
    fn matches_prefix_sum_on_random_and_extreme_inputs() {
        // One pyramid reused across sizes, as the simulation reuses it.
        let mut hp = HistoPyramid::new();
        let sizes = [
            0, 1, 2, 3, 4, 5, 7, 15, 16, 17, 63, 64, 65, 100, 255, 1000, 4097, 20_000, 70_001,
        ];
        for (seed, &n) in sizes.iter().enumerate() {
            check(&random_counts(n, seed as u64), &mut hp);
            check(&vec![0; n], &mut hp);
            check(&vec![4; n], &mut hp);
            check(&vec![1; n], &mut hp);
        }
        // Shrinking after a large build must not leave stale sums behind.
        check(&random_counts(9, 99), &mut hp);
    }

    #[test]
    fn single_survivor_is_found_anywhere() {
        let mut hp = HistoPyramid::new();
        for n in [1, 6, 33, 1025] {
            for at in [0, n / 2, n - 1] {
                let mut c = vec![0u8; n];
                c[at] = 4;
                hp.build(&c);
                assert_eq!(hp.total(), 4);
                for q in 0..4 {
                    assert_eq!(hp.locate(q), (at, q as u32));
                }
            }
        }
    }
}
