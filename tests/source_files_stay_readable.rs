//! The binary only parses and dispatches, and no source file outgrows a reading: `src/main.rs`
//! stays within [`MAIN_LINES`] and every other file under `src/` within [`FILE_LINES`], unless
//! its first line says why (`// Longer than 600 lines: …`).

use std::path::Path;

/// `main.rs` parses the command line and dispatches to `src/cli/`, one file per command.
const MAIN_LINES: usize = 300;
/// Beyond this a file holds more than one idea; split it along them.
const FILE_LINES: usize = 600;

fn files(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

#[test]
fn main_dispatches_and_files_stay_within_a_reading() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let main = std::fs::read_to_string(src.join("main.rs")).unwrap();
    assert!(
        main.lines().count() <= MAIN_LINES,
        "src/main.rs has {} lines",
        main.lines().count()
    );
    let mut all = Vec::new();
    files(&src, &mut all);
    let long: Vec<String> = all
        .iter()
        .filter_map(|p| {
            let text = std::fs::read_to_string(p).unwrap();
            let n = text.lines().count();
            let reason = text.starts_with("// Longer than 600 lines:");
            (n > FILE_LINES && !reason).then(|| format!("{} ({n} lines)", p.display()))
        })
        .collect();
    assert!(
        long.is_empty(),
        "over {FILE_LINES} lines without a reason: {long:?}"
    );
}
