//! `simulate` reports the energy budget (kinetic + gravitational + elastic) and flags a
//! spurious gain; a stiff block dropped on a floor and a body in free fall show none.

use std::process::Command;

fn simulate_stderr(scene: &str) -> String {
    let path = format!("{}/scenes/{scene}", env!("CARGO_MANIFEST_DIR"));
    let out = Command::new(env!("CARGO_BIN_EXE_powderlab"))
        .args(["simulate", &path, "--steps", "10"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[test]
fn no_spurious_gain_in_a_drop_and_a_free_fall() {
    for scene in ["stiff_block.ron", "free_fall.ron"] {
        let err = simulate_stderr(scene);
        let line = err
            .lines()
            .find(|l| l.starts_with("energy (kinetic + gravitational + elastic)"))
            .unwrap_or_else(|| panic!("{scene}: no energy line in\n{err}"));
        println!("{scene}: {line}");
        assert!(line.ends_with("no spurious gain"), "{scene}: {line}");
    }
}
