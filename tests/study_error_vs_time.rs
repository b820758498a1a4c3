//! `powderlab study error-vs-time --quick`: the whole study's machinery on a seconds-long plan
//! (every configuration in a child process, the CSV, the plot, the Pareto fronts, resume and bad
//! input). The full study is `powderlab study error-vs-time` (about 11 minutes, `docs/results/error_vs_time.md`).

#![cfg(feature = "lab")]

use serde_json::Value;
use std::path::Path;
use std::process::Command;

fn powderlab() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_powderlab"));
    c.current_dir(env!("CARGO_MANIFEST_DIR"));
    c
}

/// Directional derivative of the adjoint against a central difference (ε = 1e-7) at the quick
/// plan's coarse levels. The end-to-end bound away from contact switches is 1e-3; this
/// rollout's direction is fixed, not chosen away from the spoon's contact switches, and the
/// measured agreement is 9.6e-4 (dx = 7.5 mm) and 8.7e-5 (6.25 mm): 1e-2 leaves room for a switch
/// inside ±ε, and still fails a wrong adjoint, whose error is of order 1.
const QUICK_FD_TOL: f64 = 1e-2;

fn run_quick(out: &Path, resume: bool) -> Value {
    let mut c = powderlab();
    c.args([
        "study",
        "error-vs-time",
        "--quick",
        "--json",
        "--threads",
        "2",
        "--out",
    ])
    .arg(out);
    if resume {
        c.arg("--resume");
    }
    let o = c.output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).unwrap()
}

#[test]
fn quick_study_writes_errors_times_memory_and_pareto_fronts() {
    let dir = std::env::temp_dir().join(format!("powderlab-study-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let v = run_quick(&dir, false);
    assert!(v["failed"].as_array().unwrap().is_empty(), "{v}");
    let rows = v["rows"].as_array().unwrap();
    let quantities = [
        ("column_collapse", "runout_ratio"),
        ("column_collapse", "runout_fixed_height_ratio"),
        ("column_collapse", "runout_p99_ratio"),
        ("powder_transport", "transported_g"),
        ("powder_transport", "mean_distance_m"),
        ("powder_transport", "gradient"),
    ];
    for (case, q) in quantities {
        let mine: Vec<&Value> = rows
            .iter()
            .filter(|r| r["case"] == case && r["quantity"] == q)
            .collect();
        assert!(!mine.is_empty(), "{case} {q}");
        // Exactly one reference (the finest resolution), and its error against itself is zero.
        let refs: Vec<&&Value> = mine.iter().filter(|r| r["is_reference"] == true).collect();
        assert_eq!(refs.len(), 1, "{case} {q}");
        assert_eq!(refs[0]["error_vs_reference"].as_f64(), Some(0.0));
        let finest = mine
            .iter()
            .filter(|r| r["sweep"] == "resolution")
            .map(|r| r["dx_m"].as_f64().unwrap())
            .fold(f64::MAX, f64::min);
        assert_eq!(refs[0]["dx_m"].as_f64(), Some(finest));
        for r in &mine {
            let e = r["error_vs_reference"].as_f64().unwrap();
            assert!(e.is_finite() && e >= 0.0, "{r}");
            assert!(r["wall_s"].as_f64().unwrap() > 0.0, "{r}");
            assert!(r["peak_rss_bytes"].as_u64().unwrap() > 1 << 20, "{r}");
        }
    }
    // The collapse's fronts have a published law (the percentile and the transport do not).
    for r in rows
        .iter()
        .filter(|r| r["case"] != "column_collapse" || r["quantity"] == "runout_p99_ratio")
    {
        assert!(
            r["law_value"].is_null() && r["error_vs_law"].is_null(),
            "{r}"
        );
    }
    for r in rows
        .iter()
        .filter(|r| r["case"] == "column_collapse" && r["quantity"] != "runout_p99_ratio")
    {
        assert_eq!(r["law_value"].as_f64(), Some(1.2));
        let err = r["error_vs_law"].as_f64().unwrap();
        let want = (r["value"].as_f64().unwrap() - 1.2).abs() / 1.2;
        assert!((err - want).abs() < 1e-12);
    }
    // Every quantity with a non-zero error somewhere has a Pareto front.
    for q in ["runout_ratio", "mean_distance_m", "gradient"] {
        assert!(
            rows.iter()
                .any(|r| r["quantity"] == q && r["pareto"] == true),
            "no Pareto point for {q}"
        );
    }
    // The gradient agrees with a central difference at each resolution.
    for r in rows.iter().filter(|r| r["quantity"] == "gradient") {
        let e = r["error_vs_fd"].as_f64().unwrap();
        assert!(e <= QUICK_FD_TOL, "{r}");
    }
    // The forward-only configurations of the transport sweeps used their own knob.
    assert!(rows
        .iter()
        .any(|r| r["sweep"] == "particles_per_cell" && r["particles_per_cell"] == 1));
    assert!(rows
        .iter()
        .any(|r| r["sweep"] == "substeps" && r["substeps_per_step"] == 16));

    let csv = std::fs::read_to_string(dir.join("error_vs_time.csv")).unwrap();
    assert!(csv.starts_with("case,sweep,dx_m,"));
    assert_eq!(csv.lines().count(), rows.len() + 1);
    let svg = std::fs::read_to_string(dir.join("error_vs_time.svg")).unwrap();
    assert!(svg.contains("<svg") && svg.contains("Pareto front"));
    assert!(!dir.join("error_vs_time.svg.partial").exists());

    // Resume keeps every finished configuration: nothing runs again (a re-run would measure
    // other wall times), so the results are identical byte for byte.
    let before = std::fs::read_to_string(dir.join("results.json")).unwrap();
    let again = run_quick(&dir, true);
    assert_eq!(
        std::fs::read_to_string(dir.join("results.json")).unwrap(),
        before
    );
    assert_eq!(again["rows"], v["rows"]);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn study_refuses_bad_input_with_a_clear_message() {
    let o = powderlab().args(["study", "nonsense"]).output().unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("unrecognized subcommand 'nonsense'"), "{err}");
    assert_eq!(o.status.code(), Some(2), "{err}");

    let o = powderlab()
        .args([
            "study",
            "error-vs-time",
            "--quick",
            "--scene",
            "scenes/no_such_scene.ron",
            "--out",
        ])
        .arg(std::env::temp_dir().join("powderlab-study-bad"))
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("no_such_scene.ron"), "{err}");
}
