//! Helpers shared by the integration tests.
#![allow(dead_code)]

use powderlab::scene::Scene;
use powderlab::sim::{SimOptions, Simulation};
use std::path::{Path, PathBuf};

pub fn scene_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes")
        .join(name)
}

pub fn load(name: &str) -> Scene {
    Scene::load(scene_path(name)).unwrap_or_else(|e| panic!("{e}"))
}

pub fn parse(src: &str) -> Result<Scene, powderlab::error::SceneError> {
    Scene::parse(src, Path::new("test.ron"))
}

pub fn build(scene: &Scene, threads: usize) -> Simulation {
    Simulation::new(scene, &SimOptions::threads(Some(threads))).unwrap_or_else(|e| panic!("{e}"))
}

/// Asserts every particle field is finite.
pub fn assert_finite(sim: &mut Simulation) {
    for b in sim.body_states() {
        for (i, (x, v)) in b.x.iter().zip(&b.v).enumerate() {
            assert!(
                x.is_finite() && v.is_finite(),
                "body {} particle {i}: x {x:?} v {v:?}",
                b.name
            );
        }
        assert!(b.f.iter().all(|f| f.is_finite()) && b.c.iter().all(|c| c.is_finite()));
    }
}

/// The path of a scene of `tests/scenes`.
pub fn test_scene_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests")
        .join("scenes")
        .join(name)
}

/// A scene of `tests/scenes`.
pub fn load_test_scene(name: &str) -> Scene {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests")
        .join("scenes")
        .join(name);
    Scene::load(p).unwrap_or_else(|e| panic!("{e}"))
}

/// The official Rerun CLI (PyPI rerun-sdk==0.36.3), analytics off: `rerun` where it is on the
/// PATH, else `python3 -m rerun`, the same CLI through the Python that installed it (pip puts
/// the `rerun` script in a folder that is not always on the PATH, e.g. `~/.local/bin`).
pub fn rerun_cli() -> std::process::Command {
    let on_path = std::process::Command::new("rerun")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    let mut c = if on_path {
        std::process::Command::new("rerun")
    } else {
        let mut c = std::process::Command::new("python3");
        c.args(["-m", "rerun"]);
        c
    };
    c.env("RERUN_ANALYTICS", "0");
    c
}

/// Opens `rrd` with the official Rerun CLI (`rerun rrd stats`, PyPI rerun-sdk==0.36.3) and
/// asserts that it reads and holds every one of `entities`.
pub fn assert_rrd_has(rrd: &Path, entities: &[&str]) {
    let stats = rerun_cli()
        .args(["rrd", "stats"])
        .arg(rrd)
        .output()
        .unwrap_or_else(|e| {
            panic!("the Rerun CLI is needed for this test: pip install rerun-sdk==0.36.3 ({e})")
        });
    let text = String::from_utf8_lossy(&stats.stdout).to_string()
        + &String::from_utf8_lossy(&stats.stderr);
    assert!(
        stats.status.success(),
        "rerun rrd stats failed (the CLI comes from pip install rerun-sdk==0.36.3): {text}"
    );
    for entity in entities {
        assert!(
            text.contains(entity),
            "entity {entity} missing from:\n{text}"
        );
    }
}

/// How far an adjoint derivative may sit from the central difference `D(h)`, in multiples of
/// that difference's own error estimate `|D(h) − D(h/2)|`. Where truncation (`c·h²`) rules,
/// `D(h)` is off by 4/3 of the estimate; where round-off rules, `D(h/2)` carries about twice
/// `D(h)`'s, so the estimate is at least about `D(h)`'s error. 3 covers both with a margin; a
/// wrong adjoint is off by an amount that does not shrink with `h`, and fails.
pub const FD_ESTIMATE_FACTOR: f64 = 3.0;
/// A relative floor for when `D(h)` and `D(h/2)` agree to more digits than the losses' f64
/// sums over hundreds of particles and steps keep (about 1e-12 of the loss, divided by `h`).
pub const FD_FLOOR_REL: f64 = 1e-9;

/// Checks an adjoint derivative `ad` of `f` at 0 against central differences of `f` at steps
/// `h` and `h/2`, with the tolerance the two differences give (above). Prints both figures.
pub fn check_fd(f: impl Fn(f64) -> f64, h: f64, ad: f64, what: &str) {
    let d = |h: f64| (f(h) - f(-h)) / (2.0 * h);
    let (d1, d2) = (d(h), d(h / 2.0));
    let estimate = (d1 - d2).abs();
    let scale = d1.abs().max(ad.abs()).max(1e-300);
    let err = (ad - d1).abs();
    let allowed = FD_ESTIMATE_FACTOR * estimate + FD_FLOOR_REL * scale;
    println!(
        "{what}: adjoint {ad:.9e}, central difference {d1:.9e} (h/2: {d2:.9e}), relative error \
         {:.2e}, allowed {:.2e}",
        err / scale,
        allowed / scale
    );
    assert!(
        err <= allowed,
        "{what}: adjoint {ad:.9e} against central difference {d1:.9e}: {:.2e} relative, above \
         {FD_ESTIMATE_FACTOR}× the difference's error estimate {:.2e}",
        err / scale,
        estimate / scale
    );
}

/// Runs `cmd` and returns its output, failing the test with its stderr if it did not succeed.
pub fn succeeds(cmd: &mut std::process::Command) -> std::process::Output {
    let out = cmd.output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// A small sand column collapsing on the domain floor with plasticity active, the scene of the
/// end-to-end gradient checks (`gradient_matches_finite_differences`, `svd_precision`).
pub const SAND_COLUMN: &str = r#"Scene(
    simulation: (cells: (16, 16, 12), dx: 0.01, dt: 0.01, substeps: 10, stability: Auto),
    materials: { "sand": DruckerPrager((youngs_modulus: 2e4, poisson_ratio: 0.3, friction_deg: 30.0)) },
    bodies: [(name: "sand", material: "sand", fill: Box(min: (0.05, 0.03, 0.04), max: (0.08, 0.09, 0.07)),
              particles_per_cell: 8, lattice: Jittered(0.4), velocity: (0.2, 0.0, 0.0))],
)"#;

/// `vial_weighing.ron` at dx = 2 mm over the same domain (about 5k grains instead of 37k), with
/// walls two cells thick (the vial stands 4.5 mm from the domain's side), and the balance
/// noiseless unless `noise_mg`: the weighing scene at a cost of seconds.
pub fn coarse_weighing(noise_mg: f64) -> Scene {
    let mut s = load("vial_weighing.ron");
    s.simulation.dx = 0.002;
    s.simulation.cells = (36, 24, 16);
    s.simulation.walls.cells = 2;
    s.balance.as_mut().unwrap().noise_mg = noise_mg;
    s.validate().unwrap();
    s
}

/// The end-to-end check of a material's parameter gradients: the adjoint of
/// `SumDistance(target)` after `steps` steps of `scene` against [`check_fd`] in each named
/// parameter of the material `material` (of type `M`) at its step `h`.
#[allow(dead_code)]
pub fn check_material_gradients<M: powderlab::materials::Material>(
    scene: &Scene,
    material: &str,
    steps: usize,
    target: glam::DVec3,
    params: &[(&str, f64)],
) {
    use powderlab::adjoint::tape::{gradient, Loss, Tape};
    let loss = |s: &Scene| {
        let mut sim = build(s, 2);
        sim.run(steps, |_| {}).unwrap();
        let xs: Vec<_> = sim.body_states().into_iter().map(|b| b.x).collect();
        Loss::SumDistance(target).eval(&xs).0
    };
    let mut sim = build(scene, 2);
    let g = gradient(
        &mut sim,
        steps,
        &Loss::SumDistance(target),
        Tape::Budget(1 << 30),
    )
    .unwrap();
    for &(name, h) in params {
        let i = M::PARAMS
            .iter()
            .position(|p| p.name == name)
            .unwrap_or_else(|| panic!("{} has no parameter {name}", M::NAME));
        let with = |d: f64| {
            let mut s = scene.clone();
            let m = s
                .materials
                .get_mut(material)
                .and_then(|m| m.get_mut::<M>())
                .unwrap();
            m.set_param(i, m.param(i) + d);
            loss(&s)
        };
        check_fd(with, h, g.material_gradient(0, name).unwrap(), name);
    }
}
