//! Where the time of the connection solver goes on the Walter bench's
//! bumpy sphere ([Walter09 fig 7]): the position-normal tree's query and
//! what each of its tests removes, the candidates kept, the solver's
//! regions and Newton runs per kept triangle, against solving every
//! triangle: `cargo bench -p eikon-exact --bench walter_breakdown`.

use eikon_exact::walter::{mesh_triangles, solve_with, Mode, Options, PnTree, Stats, TreeStats};
use eikon_rng::SplitMix64 as Rng;
use glam::DVec3;
use std::time::Instant;

fn main() {
    let bumpy = eikon_mesh::BumpySphere::new(1.0, 0.15, 12, 7).unwrap();
    let mesh = bumpy.mesh(22).unwrap();
    let tree = PnTree::new(mesh_triangles(&mesh));
    let mut rng = Rng::new(12345);
    let ps: Vec<(DVec3, DVec3)> = (0..32)
        .map(|_| {
            let dv = DVec3::from(rng.direction());
            let v = dv * bumpy.radius_at(dv) * (0.2 + 0.7 * rng.unit());
            let l = DVec3::from(rng.direction()) * (2.0 + 2.0 * rng.unit());
            (v, l)
        })
        .collect();
    let opts = Options::new(Mode::Heuristic);
    let mut ts = TreeStats::default();
    let mut st = Stats::default();
    let mut with_sol = 0;
    let mut paths = 0;
    let mut cand = Vec::new();
    let reps = 20;
    let mut tq = f64::INFINITY;
    for _ in 0..reps {
        let t0 = Instant::now();
        for &(v, l) in &ps {
            cand.clear();
            tree.query_point(v, l, 1.5, &mut cand);
        }
        tq = tq.min(t0.elapsed().as_secs_f64() / 32.0);
    }
    let lists: Vec<Vec<u32>> = ps
        .iter()
        .map(|&(v, l)| {
            let mut c = Vec::new();
            tree.query_point(v, l, 1.5, &mut c);
            c
        })
        .collect();
    let mut tsolve_min = f64::INFINITY;
    for _ in 0..reps {
        let t0 = Instant::now();
        for (k, &(v, l)) in ps.iter().enumerate() {
            for &t in &lists[k] {
                std::hint::black_box(solve_with(&tree.triangles()[t as usize], v, l, 1.5, &opts));
            }
        }
        tsolve_min = tsolve_min.min(t0.elapsed().as_secs_f64());
    }
    let mut tsolve = 0.0;
    for &(v, l) in &ps {
        cand.clear();
        ts += tree.query_point(v, l, 1.5, &mut cand);
        cand.sort_unstable();
        for &t in &cand {
            let t1 = Instant::now();
            let (sols, s2) = solve_with(&tree.triangles()[t as usize], v, l, 1.5, &opts);
            tsolve += t1.elapsed().as_secs_f64();
            st.regions += s2.regions;
            st.pruned += s2.pruned;
            st.newton_runs += s2.newton_runs;
            st.newton_iterations += s2.newton_iterations;
            with_sol += usize::from(!sols.is_empty());
            paths += sols.len();
        }
    }
    let t2 = Instant::now();
    let mut all_paths = 0;
    let mut all_st = Stats::default();
    for &(v, l) in &ps {
        for t in tree.triangles() {
            let (sols, s2) = solve_with(t, v, l, 1.5, &opts);
            all_paths += sols.len();
            all_st.newton_runs += s2.newton_runs;
            all_st.regions += s2.regions;
        }
    }
    let tall = t2.elapsed().as_secs_f64();
    println!(
        "nodes {}, query {:.1} us, visited/query {:.0}, spindle {} side {} cone {}, kept {} \
         ({with_sol} with paths, {paths} paths), solve {:.1} us per kept; regions {} pruned {} \
         newton runs {} iters {}; all: {:.1} ms, {all_paths} paths, runs {} regions {}",
        tree.node_count(),
        tq * 1e6,
        ts.visited as f64 / 32.0,
        ts.spindle,
        ts.sidedness,
        ts.cone,
        ts.candidates,
        tsolve_min.min(tsolve) * 1e6 / ts.candidates as f64,
        st.regions,
        st.pruned,
        st.newton_runs,
        st.newton_iterations,
        tall * 1e3,
        all_st.newton_runs,
        all_st.regions,
    );
}
