//! `simulation.svd: F32`, the SVD stage in f32 lanes: the same bits for any thread count and for
//! any checkpoint spacing (the backward pass recomputes the same factors), and results within
//! f32's reach of the f64 stage's, on the collapsing sand column of
//! `gradient_matches_finite_differences` (plasticity active).

use glam::DVec3;
use powderlab::adjoint::tape::{gradient, Gradients, Loss, Tape};
use powderlab::components::Precision;
use powderlab::scene::Scene;

mod common;

const STEPS: usize = 8;

const SRC: &str = common::SAND_COLUMN;

fn column(svd: Precision) -> Scene {
    let mut s = common::parse(SRC).unwrap();
    s.simulation.svd = svd;
    s
}

fn run(scene: &Scene, threads: usize, tape: Tape) -> Gradients {
    let mut sim = common::build(scene, threads);
    let loss = Loss::SumDistance(DVec3::new(0.12, 0.0, 0.05));
    gradient(&mut sim, STEPS, &loss, tape).unwrap()
}

fn positions(scene: &Scene, threads: usize, steps: usize) -> Vec<DVec3> {
    let mut sim = common::build(scene, threads);
    sim.run(steps, |_| {}).unwrap();
    sim.body_states().into_iter().flat_map(|b| b.x).collect()
}

#[test]
fn f32_svd_is_bitwise_identical_on_1_and_2_threads() {
    let mut sand_box = common::load("sand_box.ron");
    sand_box.simulation.svd = Precision::F32;
    assert_eq!(positions(&sand_box, 1, 3), positions(&sand_box, 2, 3));
    let column = column(Precision::F32);
    let (one, two) = (
        run(&column, 1, Tape::Every(STEPS)),
        run(&column, 2, Tape::Every(1)),
    );
    assert_eq!(one.v0, two.v0);
    assert_eq!(one.material, two.material);
}

/// The largest particle displacement between the f32 and the f64 stage after 8 steps, as a
/// fraction of dx. Measured: 2.7e-5 (a grain moves 10–20 mm in the collapse); f32's factors
/// are good to about 1e-7 of ‖F‖, amplified by 80 substeps of plastic flow.
const POSITION_TOL_DX: f64 = 1e-4;
/// The relative difference of the material parameters' gradient (2-norm of the difference over
/// the f64 gradient's). Measured: 6.6e-5.
const MATERIAL_GRADIENT_TOL: f64 = 1e-3;
/// The same for the per-particle initial velocities. Measured: 2.8e-2. The SVD's adjoint
/// divides by `σ_j² − σ_i²`, and near rest the singular values lie within 1e-4 of each other,
/// so f32's 1e-7 in `U` and `V` reaches a particle's own gradient at the percent level; the
/// sums a skill's parameters see (as the material's) are 400× closer. The finite-difference
/// checks run in f64 for this reason.
const VELOCITY_GRADIENT_TOL: f64 = 0.1;

#[test]
fn f32_svd_stays_within_f32_precision_of_f64() {
    let (a, b) = (column(Precision::F64), column(Precision::F32));
    let (xa, xb) = (positions(&a, 2, STEPS), positions(&b, 2, STEPS));
    assert_ne!(xa, xb, "the precision setting reaches the SVD stage");
    let dx = a.simulation.dx;
    let worst = xa
        .iter()
        .zip(&xb)
        .map(|(p, q)| (*p - *q).length())
        .fold(0.0, f64::max);
    println!("largest displacement {:.3e} dx", worst / dx);
    assert!(worst <= POSITION_TOL_DX * dx, "{:.3e} dx", worst / dx);
    let (ga, gb) = (
        run(&a, 2, Tape::Every(STEPS)),
        run(&b, 2, Tape::Every(STEPS)),
    );
    let rel = |x: &[f64], y: &[f64]| {
        let d: f64 = x.iter().zip(y).map(|(p, q)| (p - q) * (p - q)).sum();
        let n: f64 = x.iter().map(|p| p * p).sum();
        (d / n).sqrt()
    };
    let flat =
        |v: &[Vec<DVec3>]| -> Vec<f64> { v.iter().flatten().flat_map(|p| p.to_array()).collect() };
    let dv = rel(&flat(&ga.v0), &flat(&gb.v0));
    let params = |g: &Gradients| -> Vec<f64> { g.material.iter().flat_map(|m| m.0).collect() };
    let dm = rel(&params(&ga), &params(&gb));
    println!("gradient differences: v0 {dv:.3e}, material {dm:.3e}");
    assert!(dm <= MATERIAL_GRADIENT_TOL, "material {dm:e}");
    assert!(dv <= VELOCITY_GRADIENT_TOL, "initial velocities {dv:e}");
}
