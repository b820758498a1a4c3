//! Long horizon: on the full `powder_transport` horizon (2.23 s of simulated time), the gradient
//! is finite and its norm neither explodes nor vanishes as the horizon grows (a third, two
//! thirds, all of it). The default scene (dx = 5 mm) runs in the default test run; the same
//! check at dx = 2.5 mm (`powder_transport_fine.ron`) is slow (about five minutes on 2 cores),
//! so it is ignored by default (and fails: the gradient explodes there):
//! `cargo test --release --test long_horizon_gradient -- --ignored --nocapture`

use glam::DVec3;
use powderlab::adjoint::loss::scene_loss;
use powderlab::adjoint::tape::{gradient, Tape};

mod common;

/// Growth allowed between horizons one third apart. In free flight `∂x_T/∂v₀ = T`, so the
/// gradient of a distance loss grows in proportion to the horizon: ×2, then ×1.5 between these
/// horizons. Granular flow dissipates, so a perturbation's effect grows less and stays once the
/// powder rests; more than 3× faster (or slower) than that is an explosion (or a vanishing), not
/// physics. The default scene measures 1.2× and 1.0× (`docs/results/gradients.md`).
const MAX_GROWTH: f64 = 3.0;

#[test]
fn gradient_stays_finite_and_bounded_over_the_horizon() {
    check("powder_transport.ron");
}

/// It fails today: the gradient grows about tenfold every third of the horizon at this
/// resolution (`docs/results/gradients.md`, "Long horizon").
#[test]
#[ignore = "slow study: about 5 minutes on 2 cores; fails (an exploding gradient, see the gradients page)"]
fn gradient_stays_finite_and_bounded_over_the_horizon_at_the_fine_resolution() {
    check("powder_transport_fine.ron");
}

fn check(file: &str) {
    let scene = common::load(file);
    let horizon = common::build(&scene, 2).horizon;
    let loss = scene_loss(&scene);
    let mut norms = Vec::new();
    for steps in [horizon / 3, 2 * horizon / 3, horizon] {
        let mut sim = common::build(&scene, 2);
        let t = std::time::Instant::now();
        let g = gradient(&mut sim, steps, &loss, Tape::Budget(1 << 30))
            .unwrap_or_else(|e| panic!("{steps} steps: {e}"));
        let v0: f64 =
            g.v0.iter()
                .flatten()
                .map(|v| v.length_squared())
                .sum::<f64>()
                .sqrt();
        let theta = scene.skill_gradients(&g.controls)[0].1;
        let th: f64 = theta.iter().map(|x| x * x).sum::<f64>().sqrt();
        let ctrl: f64 = g.controls[0]
            .1
            .iter()
            .flatten()
            .map(|x| x * x)
            .sum::<f64>()
            .sqrt();
        println!(
            "{steps} steps: loss {:.6e}, |dL/dv0| {v0:.4e}, |dL/dTheta| {th:.4e} {theta:?}, |dL/du| {ctrl:.4e}, |dL/dE| {:.4e}, tape {:.1} MB (k = {}), peak RSS {:.1} MB, {:.1} s",
            g.loss,
            g.material_gradient(0, "youngs_modulus").unwrap().abs(),
            g.tape_bytes as f64 / 1e6,
            g.checkpoint_every,
            powderlab::util::peak_rss_bytes() as f64 / 1e6,
            t.elapsed().as_secs_f64()
        );
        assert!(v0.is_finite() && th.is_finite() && ctrl.is_finite());
        assert!(g.x0.iter().flatten().all(|x: &DVec3| x.is_finite()));
        norms.push((v0, ctrl));
    }
    for w in norms.windows(2) {
        for (a, b) in [(w[0].0, w[1].0), (w[0].1, w[1].1)] {
            assert!(a > 0.0 && b > 0.0, "a vanished gradient: {norms:?}");
            assert!(
                b / a < MAX_GROWTH && a / b < MAX_GROWTH,
                "exploding or vanishing: {norms:?}"
            );
        }
    }
}
