//! `powderlab study growth --quick`: the growth study's machinery on four small configurations
//! (each in a child process, the JSON, CSV and SVG). Timings are reported, never asserted; the
//! full study is `powderlab study growth` (`docs/results/performance.md`, "Growth").

#![cfg(feature = "lab")]

use serde_json::Value;
use std::process::Command;

#[test]
fn quick_growth_study_measures_every_configuration_and_writes_its_files() {
    let dir = std::env::temp_dir().join(format!("powderlab-growth-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let o = Command::new(env!("CARGO_BIN_EXE_powderlab"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args([
            "study",
            "growth",
            "--quick",
            "--json",
            "--threads",
            "2",
            "--out",
        ])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: Value = serde_json::from_slice(&o.stdout).unwrap();
    let results = v["results"].as_array().unwrap();
    assert_eq!(results.len(), 6, "{v}");
    for r in results {
        let cells = r["config"]["cells"].as_u64().unwrap();
        // The quick plan's block is 4 cells wide: (2·4)³ particles on the regular lattice.
        assert_eq!(r["particles"], 512, "{r}");
        assert_eq!(r["nodes"].as_u64().unwrap(), cells.pow(3));
        assert_eq!(r["threads"], 2);
        let per = r["seconds_per_substep"].as_f64().unwrap();
        let timed = r["substeps_timed"].as_u64().unwrap();
        // The quick plan times one step of ⌈20·cells/48⌉ substeps.
        assert_eq!(timed, (20 * cells).div_ceil(48));
        assert!(per > 0.0 && per.is_finite());
        let rate = r["particle_substeps_per_s"].as_f64().unwrap();
        assert!((rate * per / 512.0 - 1.0).abs() < 1e-9);
        assert!(r["peak_rss_bytes"].as_u64().unwrap() > 0);
    }
    // The spread the page quotes is the fastest over the slowest particle-series rate of these
    // very results (not a figure carried over from elsewhere).
    let rates: Vec<f64> = results
        .iter()
        .filter(|r| r["config"]["series"] == "particles")
        .map(|r| r["particle_substeps_per_s"].as_f64().unwrap())
        .collect();
    assert!(rates.len() >= 2, "{v}");
    let hi = rates.iter().copied().fold(f64::MIN, f64::max);
    let lo = rates.iter().copied().fold(f64::MAX, f64::min);
    assert_eq!(
        v["particle_series_max_over_min_throughput"].as_f64(),
        Some(hi / lo),
        "{rates:?}"
    );
    let csv = std::fs::read_to_string(dir.join("growth.csv")).unwrap();
    assert_eq!(csv.lines().count(), 7, "{csv}");
    let svg = std::fs::read_to_string(dir.join("growth.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("ns per particle-substep"));
    let json: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("growth.json")).unwrap()).unwrap();
    assert_eq!(json.as_array().unwrap().len(), 6);
    // The dense twin of each grid configuration ends in the active grid's state, to the bit.
    let gain = v["active_grid_gain"].as_array().unwrap();
    assert_eq!(gain.len(), 2, "{v}");
    for g in gain {
        assert_eq!(g["same_bits"], true, "{g}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn unknown_study_is_refused_by_name() {
    let o = Command::new(env!("CARGO_BIN_EXE_powderlab"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args(["study", "growht"])
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("growht") && err.contains("growth"), "{err}");
}

/// The growth study runs its own `sand_box` variants and reruns everything: `--scene` and
/// `--resume` are not among its arguments, so they are refused (exit 2) with a message naming
/// them, not silently ignored.
#[test]
fn growth_study_refuses_the_options_it_does_not_use() {
    for args in [
        &["--scene", "scenes/powder_transport.ron"][..],
        &["--resume"][..],
    ] {
        let o = Command::new(env!("CARGO_BIN_EXE_powderlab"))
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .args(["study", "growth", "--quick"])
            .args(args)
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(2), "{args:?} was not refused");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(&format!("'{}'", args[0])), "{err}");
    }
}
