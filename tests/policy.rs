//! The skill policy (seed B's Sim2Real step): the randomised scenes, the dataset file, the
//! network's fit, REINFORCE, the refusal of a policy of another feature layout, and the
//! commands end to end on a small scene.
#![cfg(feature = "lab")]

use powderlab::lab::policy::dataset::{self, gauss_newton, Sample};
use powderlab::lab::policy::features::layout;
use powderlab::lab::policy::knob;
use powderlab::lab::policy::net::{fit, is_answer, select, train, usable, Policy, TrainConfig};
use powderlab::lab::policy::reinforce::{finetune, ReinforceConfig};
use powderlab::scene::randomize::Draw;
use powderlab::scene::Scene;
use powderlab::skills::Theta;
use powderlab::util::SplitMix64;
use std::path::{Path, PathBuf};
use std::process::Command;

mod common;

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("powderlab-policy-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

const RANDOMIZE: &str = r#"    randomize: Some((
        source: "source_cup",
        fill_height: Some((0.015, 0.020)),
        friction_deg: Some((25.0, 35.0)),
        youngs_modulus: Some((4e3, 6e3)),
        source_x: Some((0.038, 0.042)),
        cup_distance: Some((0.07, 0.09)),
        target_g: Some((1.0, 3.0)),
    )),
"#;

/// The small transport scene with `randomize` as its last field.
fn tiny_with(dir: &Path, randomize: &str) -> PathBuf {
    let base =
        std::fs::read_to_string(common::scene_path("../tests/scenes/tiny_transport.ron")).unwrap();
    let text = base.trim_end().strip_suffix(')').unwrap().to_string() + randomize + ")\n";
    let p = dir.join("tiny_policy.ron");
    std::fs::write(&p, text).unwrap();
    p
}

fn draw(k: u64) -> Draw {
    Draw {
        fill_height: 0.02 + 0.001 * k as f64,
        friction_deg: 30.0,
        density: 1500.0,
        youngs_modulus: 5e3,
        source_x: 0.06,
        cup_distance: 0.12,
        target_g: 2.0,
        packing_seed: u64::MAX - k,
    }
}

/// The knob of [`synthetic`]'s samples: a smooth function of two features, with a fold that two
/// hidden units cannot follow.
fn knob_of(x: &[f64]) -> f64 {
    0.8 * (2.5 * x[0]).sin() * (1.5 * x[1]).cos()
}

/// Samples on the knob's family whose knob is [`knob_of`] their first two features; the others
/// are constant.
fn synthetic(n: usize) -> Vec<Sample> {
    let f = layout().len();
    let mut rng = SplitMix64(3);
    (0..n)
        .map(|k| {
            let x: Vec<f64> = (0..f)
                .map(|i| {
                    if i < 2 {
                        rng.uniform_in(-1.0, 1.0)
                    } else {
                        0.1 * i as f64
                    }
                })
                .collect();
            let mut theta = knob::CANONICAL;
            theta[knob::KNOB] = knob_of(&x);
            theta[3] = 0.5 * x[1];
            Sample {
                scene: k,
                copy: k % 3,
                draw: draw(k as u64),
                features: x,
                theta,
                loss: 0.01 * k as f64,
                // Within 0.1 g but for every 50th, which misses by 2 g short of a target that
                // a deeper scoop would reach.
                indicator: if k % 50 == 49 {
                    2.0
                } else {
                    -0.0005 * k as f64
                },
                start_loss: 0.02 * k as f64,
                rollouts: 20.0,
                particle_substeps: 1.25e7,
                hindsight: k % 5 == 0,
            }
        })
        .collect()
}

#[test]
fn the_dataset_file_round_trips_every_field() {
    let d = scratch("roundtrip");
    let samples = synthetic(7);
    let path = d.join("dataset.safetensors");
    dataset::write(&path, &samples).unwrap();
    assert_eq!(dataset::read(&path).unwrap(), samples);
    // A file that is not a dataset is refused by name.
    std::fs::write(&path, b"not a file of tensors").unwrap();
    let e = format!("{:#}", dataset::read(&path).unwrap_err());
    assert!(
        e.contains("dataset.safetensors") && e.contains("safetensors"),
        "{e}"
    );
}

#[test]
fn the_mlp_fits_a_small_smooth_map() {
    let samples = synthetic(200);
    let var: f64 = {
        let k: Vec<f64> = samples.iter().map(|s| s.theta[knob::KNOB]).collect();
        let m = k.iter().sum::<f64>() / 200.0;
        k.iter().map(|v| (v - m).powi(2)).sum::<f64>() / 200.0
    };
    let cfg = TrainConfig {
        epochs: 600,
        val_every: 0,
        ..TrainConfig::default()
    };
    // The labels that miss their target by 2 g are not learnt.
    assert_eq!(usable(&samples, &cfg).len(), 196);
    let (policy, curve) = train(&samples, &cfg).unwrap();
    let last = curve.last().unwrap().train_mse;
    // The map is smooth and noiseless: the fit must explain at least 95 % of the knob's
    // variance.
    assert!(last < 0.05 * var, "MSE {last} against a variance of {var}");
    let s = &samples[17];
    let got = policy.act(&s.features).unwrap();
    assert_eq!(got.len(), powderlab::lab::policy::net::OUTPUTS);
    let err = (got[0] - s.theta[knob::KNOB]).powi(2);
    assert!(err < 0.2 * var, "one sample's error {err}");
}

/// A label is learnt when it is its scene's answer: within the tolerance, or at the family's
/// end with the target beyond it; not a copy whose refinement fell short.
#[test]
fn only_answers_are_learnt() {
    let mut s = synthetic(1).remove(0);
    let tol = TrainConfig::default().max_label_error_g;
    let at = |s: &mut Sample, k: f64, ind: f64| {
        s.theta[knob::KNOB] = k;
        s.indicator = ind;
    };
    at(&mut s, 0.3, 0.5 * tol);
    assert!(is_answer(&s, tol));
    at(&mut s, 0.3, -2.0 * tol);
    assert!(!is_answer(&s, tol), "short of the target inside the box");
    // The deepest scoop holds less than the target: nothing doses closer.
    at(&mut s, 1.0, 0.8);
    assert!(is_answer(&s, tol));
    // The deepest scoop holds more than the target: a shallower one would dose closer.
    at(&mut s, 1.0, -0.8);
    assert!(!is_answer(&s, tol));
    at(&mut s, -1.0, -0.8);
    assert!(is_answer(&s, tol));
    at(&mut s, -1.0, 0.8);
    assert!(!is_answer(&s, tol));
}

/// The width is chosen on the training set's own validation split: the chosen network is the
/// width of lowest validation error, and it is as good on that split as its table says.
#[test]
fn the_width_is_chosen_by_the_validation_split() {
    let samples = synthetic(120);
    let cfg = TrainConfig {
        epochs: 300,
        ..TrainConfig::default()
    };
    let (fit, table) = select(&samples, &cfg, &[2, 32]).unwrap();
    assert_eq!(table.len(), 2);
    let (h, v) = *table.iter().min_by(|a, b| a.1.total_cmp(&b.1)).unwrap();
    assert_eq!(fit.policy.hidden, h);
    assert_eq!(fit.policy.members.len(), cfg.members);
    assert_eq!(fit.val_mse, v);
    // Two units cannot carry the fold of two features that a 32-wide net fits.
    assert_eq!(h, 32, "{table:?}");
}

/// The ensemble's answer is its members' mean: on the validation split its error is at most
/// their mean error (the square is convex), and its file keeps every member.
#[test]
fn an_ensemble_is_the_mean_of_its_members() {
    let samples = synthetic(120);
    let cfg = TrainConfig {
        epochs: 200,
        hidden: 16,
        members: 3,
        ..TrainConfig::default()
    };
    let f = fit(&samples, &cfg).unwrap();
    assert_eq!(f.policy.members.len(), 3);
    let members: Vec<Policy> = (0..3)
        .map(|m| {
            train(
                &samples,
                &TrainConfig {
                    seed: cfg.seed + m,
                    ..cfg
                },
            )
            .unwrap()
            .0
        })
        .collect();
    let x = &samples[4].features;
    let mean = members.iter().map(|p| p.act(x).unwrap()[0]).sum::<f64>() / 3.0;
    assert!((f.policy.act(x).unwrap()[0] - mean).abs() < 1e-12);
    // A member taken out is the network trained alone with its seed.
    assert_eq!(
        f.policy.member(1).unwrap().act(x).unwrap(),
        members[1].act(x).unwrap()
    );
    let (val, mut each) = (f.val_mse, 0.0);
    for p in &members {
        let v: Vec<&Sample> = usable(&samples, &cfg)
            .into_iter()
            .filter(|s| s.scene % cfg.val_every == cfg.val_every - 1)
            .collect();
        each += v
            .iter()
            .map(|s| (p.act(&s.features).unwrap()[0] - s.theta[knob::KNOB]).powi(2))
            .sum::<f64>()
            / v.len() as f64
            / 3.0;
    }
    assert!(
        val <= each + 1e-12,
        "ensemble {val} against its members' mean {each}"
    );
    let d = scratch("ensemble");
    let path = d.join("policy.safetensors");
    f.policy.save(&path).unwrap();
    let q = Policy::load(&path, &layout(), powderlab::lab::policy::net::OUTPUTS).unwrap();
    assert_eq!(q.members.len(), 3);
    assert_eq!(q.fingerprint().unwrap(), f.policy.fingerprint().unwrap());
    // Members of other standardisations are not one policy.
    let names = layout();
    let n = names.len();
    let other = Policy::new(names, 16, vec![1.0; n], vec![1.0; n], &[0.0], 0).unwrap();
    assert!(Policy::ensemble(vec![q, other]).is_err());
}

#[test]
fn reinforce_improves_a_contextual_bandit() {
    // Each context asks for its own Θ: a quarter of its first two features.
    let names: Vec<String> = (0..3).map(|i| format!("x{i}")).collect();
    let policy = Policy::new(names, 16, vec![0.0; 3], vec![1.0; 3], &[0.0; 5], 1).unwrap();
    let mut rng = SplitMix64(9);
    let contexts: Vec<Vec<f64>> = (0..8)
        .map(|_| (0..3).map(|_| rng.uniform_in(-1.0, 1.0)).collect())
        .collect();
    let want = |c: &[f64]| [0.6, -0.4, 0.25 * c[0], 0.25 * c[1], 0.3];
    let loss = |p: &Policy| -> f64 {
        contexts
            .iter()
            .map(|c| {
                let t = p.act(c).unwrap();
                let w = want(c);
                (0..5).map(|i| (t[i] - w[i]).powi(2)).sum::<f64>()
            })
            .sum::<f64>()
            / contexts.len() as f64
    };
    let before = loss(&policy);
    let cfg = ReinforceConfig {
        iterations: 150,
        batch: 16,
        sigma: 0.1,
        lr: 1e-2,
        seed: 4,
    };
    let reward = |_: usize, _: usize, ctx: usize, theta: &[f64]| -> anyhow::Result<f64> {
        let w = want(&contexts[ctx]);
        Ok(-(0..5).map(|i| (theta[i] - w[i]).powi(2)).sum::<f64>())
    };
    let its = finetune(&policy, &contexts, &cfg, &reward, &mut |_| {}).unwrap();
    let after = loss(&policy);
    assert_eq!(its.len(), 150);
    // Only sampled rewards reach the learner; it must still cut the mean's loss by 3×.
    assert!(after < before / 3.0, "loss {before} -> {after}");
}

#[test]
fn a_policy_of_another_feature_layout_is_refused_by_name() {
    let d = scratch("layout");
    let names: Vec<String> = ["fill_height", "friction_deg", "target_g"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    let p = Policy::new(names, 8, vec![0.0; 3], vec![1.0; 3], &[0.0], 0).unwrap();
    let path = d.join("old.safetensors");
    p.save(&path).unwrap();
    let e = match Policy::load(&path, &layout(), powderlab::lab::policy::net::OUTPUTS) {
        Ok(_) => panic!(
            "a policy of 3 features was loaded for a layout of {}",
            layout().len()
        ),
        Err(e) => format!("{e:#}"),
    };
    assert!(e.contains("old.safetensors"), "{e}");
    assert!(
        e.contains("feature layout") && e.contains("3 features"),
        "{e}"
    );
    assert!(e.contains("policy train"), "{e}");
    assert_eq!(e.lines().count(), 1, "{e}");
    // Its own layout loads, with the same answers.
    let names = p.layout.clone();
    let q = Policy::load(&path, &names, powderlab::lab::policy::net::OUTPUTS).unwrap();
    assert_eq!(q.fingerprint().unwrap(), p.fingerprint().unwrap());
    assert_eq!(
        q.act(&[0.1, 0.2, 0.3]).unwrap(),
        p.act(&[0.1, 0.2, 0.3]).unwrap()
    );
    // A network of all five of Θ's components is not a dosing policy (its knob alone).
    let five = Policy::new(
        p.layout.clone(),
        8,
        vec![0.0; 3],
        vec![1.0; 3],
        &[0.0; 5],
        0,
    )
    .unwrap();
    five.save(&path).unwrap();
    let e = format!(
        "{:#}",
        Policy::load(&path, &names, powderlab::lab::policy::net::OUTPUTS)
            .err()
            .unwrap()
    );
    assert!(
        e.contains("old.safetensors") && e.contains("metadata.outputs: 5, expected 1"),
        "{e}"
    );
    assert!(e.contains("policy train") && e.lines().count() == 1, "{e}");
}

#[test]
fn a_gauss_newton_step_lands_on_the_root_of_a_linear_dose() {
    // r(θ) = a·θ − b, L = r²: one step from a point within reach solves r = 0.
    let a = [0.3, -0.2, 0.1, 0.0, 0.4];
    let b = 0.05;
    let theta = Theta([0.1, 0.0, 0.0, 0.0, 0.0]);
    let r = a.iter().zip(&theta).map(|(x, y)| x * y).sum::<f64>() - b;
    let g: [f64; 5] = std::array::from_fn(|i| 2.0 * r * a[i]);
    let next = gauss_newton(theta, r * r, g);
    let r2 = a.iter().zip(&next).map(|(x, y)| x * y).sum::<f64>() - b;
    assert!(r2.abs() < 1e-12, "residual {r2}");
}

#[test]
fn randomised_scenes_are_drawn_reproducibly_and_move_the_spoon_with_the_source() {
    let d = scratch("draw");
    let scene = Scene::load(tiny_with(&d, RANDOMIZE)).unwrap();
    let spec = dataset::spec_of(&scene).unwrap();
    let a = dataset::draw_scene(spec, &scene, 0, 3);
    assert_eq!(a, dataset::draw_scene(spec, &scene, 0, 3));
    assert_ne!(a, dataset::draw_scene(spec, &scene, 0, 4));
    assert!((0.07..=0.09).contains(&a.cup_distance) && (1.0..=3.0).contains(&a.target_g));
    // A quantity without a range keeps the scene's value.
    assert_eq!(a.density, 1500.0);
    let s = spec.apply(&scene, &a).unwrap();
    let x = |s: &Scene, n: &str| s.colliders.iter().find(|c| c.name == n).unwrap().position.0;
    assert!((x(&s, "source_cup") - a.source_x).abs() < 1e-15);
    assert!((x(&s, "target_cup") - (a.source_x + a.cup_distance)).abs() < 1e-15);
    let moved = x(&s, "spoon") - x(&scene, "spoon");
    assert!((moved - (a.source_x - 0.04)).abs() < 1e-15);
    assert_eq!(s.simulation.seed, a.packing_seed);
}

/// The labeller's search runs the shallowest and deepest scoops first and keeps every other
/// trial inside them; each of its rollouts, relabelled with its own mass as the target, is
/// solved exactly by its Θ when the relabelled scene is built and run afresh.
#[test]
fn the_knob_search_brackets_and_its_hindsight_labels_are_exact() {
    let d = scratch("knob");
    let scene = Scene::load(tiny_with(&d, RANDOMIZE)).unwrap();
    let spec = dataset::spec_of(&scene).unwrap();
    let draw = dataset::draw_scene(spec, &scene, 0, 1);
    let (problem, _) = dataset::problem_of(&scene, &draw).unwrap();
    let trace = knob::search(&problem, &draw, 4).unwrap();
    assert!((2..=4).contains(&trace.len()), "{}", trace.len());
    assert_eq!((trace[0].0, trace[1].0), (-1.0, 1.0));
    assert!(trace[2..].iter().all(|(s, _)| s.abs() < 1.0));
    // Every rollout qualifies under a range wide enough for any mass.
    let wide = powderlab::scene::randomize::Randomization {
        target_g: Some((0.0, 1e9)),
        ..spec.clone()
    };
    let rollouts: Vec<_> = trace
        .iter()
        .map(|(s, o)| (knob::family(&problem, &draw, *s), o.clone()))
        .collect();
    let labels = dataset::hindsight(&wide, &problem, (1, 0), &draw, &rollouts);
    assert_eq!(labels.len(), trace.len());
    for (l, (_, o)) in labels.iter().zip(&trace) {
        assert!(l.hindsight && l.draw.target_g == o.transported);
        let (p, f) = dataset::problem_of(&scene, &l.draw).unwrap();
        assert_eq!(f, l.features);
        let again = p.evaluate(l.theta, false, true).unwrap();
        assert_eq!(again.indicator, 0.0, "{} g", again.transported);
    }
}

#[test]
fn a_bad_range_is_refused_in_one_line_naming_the_field() {
    let d = scratch("bad");
    for (from, to, field) in [
        (
            "target_g: Some((1.0, 3.0))",
            "target_g: Some((3.0, 1.0))",
            "randomize.target_g",
        ),
        (
            "friction_deg: Some((25.0, 35.0))",
            "friction_deg: Some((25.0, 95.0))",
            "randomize.friction_deg",
        ),
        (
            "cup_distance: Some((0.07, 0.09))",
            "cup_distance: Some((0.07, 0.3))",
            "randomize.cup_distance",
        ),
        (
            "source: \"source_cup\"",
            "source: \"spoon\"",
            "randomize.source",
        ),
    ] {
        let p = tiny_with(&d, &RANDOMIZE.replace(from, to));
        let out = Command::new(env!("CARGO_BIN_EXE_powderlab"))
            .args(["policy", "dataset"])
            .arg(&p)
            .arg("--dir")
            .arg(d.join("out"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr).trim().to_string();
        assert_eq!(out.status.code(), Some(2), "{err}");
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(
            err.contains(field) && err.contains("tiny_policy.ron"),
            "{field}: {err}"
        );
    }
}

fn powderlab(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_powderlab"))
        .args(args)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{args:?}: {err}");
    String::from_utf8_lossy(&out.stdout).to_string()
}

#[test]
fn the_commands_run_end_to_end_on_a_small_scene_and_resume() {
    let d = scratch("e2e");
    let scene = tiny_with(&d, RANDOMIZE);
    let (s, dir) = (scene.to_str().unwrap(), d.join("run"));
    let dir = dir.to_str().unwrap();
    let ds = [
        "policy",
        "dataset",
        s,
        "--dir",
        dir,
        "--scenes",
        "3",
        "--budget",
        "2",
        "--augment",
        "1",
    ];
    let out = powderlab(&ds);
    let samples = dataset::read(&Path::new(dir).join("dataset.safetensors")).unwrap();
    let n = samples.len();
    assert!(out.contains(&format!("{n} samples")), "{out}");
    // Three scenes and a copy of each, searched; the hindsight samples are the rollouts that
    // delivered a mass in the target's range, each the exact answer to it.
    assert_eq!(samples.iter().filter(|x| !x.hindsight).count(), 6);
    assert!(samples
        .iter()
        .filter(|x| !x.hindsight)
        .all(|x| x.loss.is_finite() && x.rollouts > 0.0));
    assert!(samples
        .iter()
        .filter(|x| x.hindsight)
        .all(|x| x.indicator == 0.0 && (1.0..=3.0).contains(&x.draw.target_g)));
    // A rerun finds every scene done and writes the same file.
    powderlab(&ds);
    assert_eq!(
        dataset::read(&Path::new(dir).join("dataset.safetensors")).unwrap(),
        samples
    );
    // Asked for one scene more, the same folder grows by it and keeps the others as they were.
    let grown = ds.map(|a| if a == "3" { "4" } else { a });
    powderlab(&grown);
    let more = dataset::read(&Path::new(dir).join("dataset.safetensors")).unwrap();
    assert_eq!(more[..n], samples[..]);
    assert!(more[n..].iter().all(|x| x.scene == 3));
    assert_eq!(more.iter().filter(|x| !x.hindsight).count(), 8);
    // Other settings are still refused.
    let other = ds.map(|a| if a == "2" { "5" } else { a });
    let out = Command::new(env!("CARGO_BIN_EXE_powderlab"))
        .args(other)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    powderlab(&ds);
    // Two rollouts per scene solve nothing: every label is kept for this test.
    let out = powderlab(&[
        "policy",
        "train",
        "--dir",
        dir,
        "--epochs",
        "50",
        "--hidden",
        "8",
        "--max-label-error-g",
        "100",
    ]);
    assert!(
        out.contains(&format!("fitted on {n} of {n} samples")),
        "{out}"
    );
    let out = powderlab(&[
        "policy",
        "finetune",
        s,
        "--dir",
        dir,
        "--iterations",
        "1",
        "--batch",
        "2",
    ]);
    assert!(out.contains("2 episodes"), "{out}");
    let out = powderlab(&[
        "policy", "eval", s, "--dir", dir, "--scenes", "1", "--budget", "2",
    ]);
    for m in [
        "policy",
        "finetuned",
        "random",
        "optimiser",
        "repacked",
        "warm",
    ] {
        assert!(out.contains(&format!("| {m} |")), "{m}: {out}");
    }
    let written = d.join("applied.ron");
    let policy = Path::new(dir).join("policy.safetensors");
    let out = powderlab(&[
        "policy",
        "apply",
        s,
        "--policy",
        policy.to_str().unwrap(),
        "--write",
        written.to_str().unwrap(),
    ]);
    assert!(out.starts_with("theta: ("), "{out}");
    let applied = Scene::load(&written).unwrap();
    assert!(applied.randomize.is_some());
}
