//! The Chamfer distance between a simulated particle cloud `A` and an observed point cloud `B`,
//! and its adjoint:
//!
//! `L = (1/|A|) Σ_a ‖a − nn_B(a)‖² + (1/|B|) Σ_b ‖b − nn_A(b)‖²`
//!
//! with `nn_X(q)` the point of `X` nearest `q` (a k-d tree, `kiddo`). Its gradient with respect
//! to a simulated point `a` is `2(a − nn_B(a))/|A| + Σ_{b: nn_A(b) = a} 2(a − b)/|B|`: each point
//! is pulled to its nearest observation, and each observation pulls its nearest simulated point.
//! The nearest-neighbour assignment is piecewise constant in `A`, so `L` is continuous and
//! piecewise quadratic, differentiable wherever no point is equidistant from two others (almost
//! everywhere; at a tie the tree's deterministic choice gives one of the one-sided gradients).
//! The two terms are averages, so clouds of different sizes (a depth camera's points against
//! the particles) weigh alike.

use glam::DVec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use std::sync::Arc;

/// An observed point cloud with its k-d tree, built once.
#[derive(Clone, Debug)]
pub struct ObservedCloud {
    pub points: Vec<DVec3>,
    tree: Arc<ImmutableKdTree<f64, 3>>,
}

impl ObservedCloud {
    /// `points` must be non-empty and finite (the observation's reader checks both).
    pub fn new(points: Vec<DVec3>) -> ObservedCloud {
        let tree = Arc::new(tree(&points));
        ObservedCloud { points, tree }
    }
}

fn tree(points: &[DVec3]) -> ImmutableKdTree<f64, 3> {
    let a: Vec<[f64; 3]> = points.iter().map(|p| p.to_array()).collect();
    ImmutableKdTree::new_from_slice(&a)
}

/// The Chamfer distance (m²) and its gradient with respect to each simulated point.
pub fn chamfer(sim: &[DVec3], obs: &ObservedCloud) -> (f64, Vec<DVec3>) {
    if sim.is_empty() || obs.points.is_empty() {
        return (0.0, vec![DVec3::ZERO; sim.len()]);
    }
    let (na, nb) = (sim.len() as f64, obs.points.len() as f64);
    let mut l = 0.0;
    let mut g: Vec<DVec3> = sim
        .iter()
        .map(|a| {
            let nn = obs.tree.nearest_one::<SquaredEuclidean>(&a.to_array());
            let d = *a - obs.points[nn.item as usize];
            l += d.length_squared() / na;
            2.0 * d / na
        })
        .collect();
    let sim_tree = tree(sim);
    for b in &obs.points {
        let nn = sim_tree.nearest_one::<SquaredEuclidean>(&b.to_array());
        let a = nn.item as usize;
        let d = sim[a] - *b;
        l += d.length_squared() / nb;
        g[a] += 2.0 * d / nb;
    }
    (l, g)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The loss is quadratic between assignment changes, so a central difference is exact up to
    /// rounding (~1e-16 · L / 1e-7) when the step crosses no tie: 1e-7 relative is loose.
    const FD_TOL: f64 = 1e-7;

    fn scatter(n: usize, seed: f64) -> Vec<DVec3> {
        (0..n)
            .map(|k| {
                let t = k as f64 + seed;
                DVec3::new(
                    (t * 0.618_034).fract(),
                    (t * 0.377_123).fract(),
                    (t * 0.853_211).fract(),
                ) * 0.05
            })
            .collect()
    }

    #[test]
    fn chamfer_adjoint_matches_central_differences() {
        let sim = scatter(40, 0.3);
        let obs = ObservedCloud::new(scatter(55, 7.1));
        let (_, g) = chamfer(&sim, &obs);
        let eps = 1e-7;
        let mut worst: f64 = 0.0;
        for i in 0..sim.len() {
            for d in 0..3 {
                let mut p = sim.clone();
                p[i][d] += eps;
                let mut q = sim.clone();
                q[i][d] -= eps;
                let fd = (chamfer(&p, &obs).0 - chamfer(&q, &obs).0) / (2.0 * eps);
                let scale = fd.abs().max(g[i][d].abs()).max(1e-9);
                worst = worst.max((fd - g[i][d]).abs() / scale);
            }
        }
        assert!(worst < FD_TOL, "worst relative error {worst:e}");
    }

    #[test]
    fn chamfer_is_zero_on_identical_clouds_and_grows_with_a_shift() {
        let a = scatter(30, 0.0);
        let obs = ObservedCloud::new(a.clone());
        assert_eq!(chamfer(&a, &obs).0, 0.0);
        // A shift far smaller than the spacing keeps every assignment: L = 2·s².
        let s = 1e-5;
        let shifted: Vec<DVec3> = a.iter().map(|p| *p + DVec3::X * s).collect();
        let l = chamfer(&shifted, &obs).0;
        assert!((l - 2.0 * s * s).abs() < 1e-20, "{l:e}");
    }
}
