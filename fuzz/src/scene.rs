//! AFL++ target: the scene loader on arbitrary bytes. Parse, validate and prepare within a
//! memory limit must never panic, and a refusal must be one line that names the file; AFL
//! records a broken invariant as a crash.
//!
//! ```sh
//! cargo install cargo-afl
//! cd fuzz && cargo afl build --release
//! cargo afl fuzz -i ../scenes -o out target/release/scene
//! ```

use std::path::Path;

/// The memory the loader may plan for, as in `tests/scene_fuzz.rs`.
const LOADER_LIMIT: u64 = 256 << 20;

fn main() {
    afl::fuzz!(|data: &[u8]| {
        let file = Path::new("afl.ron");
        let outcome = powderlab::scene::Scene::parse_bytes(data, file)
            .and_then(|s| s.prepare_within(Some(LOADER_LIMIT)).map(|_| ()));
        if let Err(e) = outcome {
            let m = e.to_string();
            assert!(!m.contains('\n'), "a refusal of more than one line: {m}");
            assert!(m.starts_with("afl.ron"), "a refusal without the file: {m}");
        }
    });
}
