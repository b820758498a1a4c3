//! The scenes compiled into the library (`scene::shipped`) are the files of `scenes/`, every one
//! of them, and load to the same scene by name as from their file; a name that is neither a
//! file nor a shipped scene is refused with the shipped names listed.

use powderlab::error::SceneError;
use powderlab::scene::{shipped, Scene};
use std::path::Path;

fn strip(s: Scene) -> Scene {
    Scene {
        source: String::new(),
        ..s
    }
}

#[test]
fn the_table_holds_every_scene_file_and_nothing_else() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
    let mut files: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter_map(|f| f.strip_suffix(".ron").map(str::to_string))
        .collect();
    files.sort();
    let table: Vec<String> = shipped::names().map(str::to_string).collect();
    assert_eq!(
        table, files,
        "scene::shipped::SHIPPED must list every scenes/*.ron, in name order"
    );
}

#[test]
fn a_shipped_scene_is_its_file() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    for name in shipped::names() {
        let by_name = Scene::shipped(name).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(
            by_name.path,
            Path::new("scenes").join(format!("{name}.ron"))
        );
        let file = Scene::load(root.join("scenes").join(format!("{name}.ron"))).unwrap();
        assert_eq!(
            std::fs::read_to_string(root.join(&by_name.path)).unwrap(),
            shipped::text(name).unwrap()
        );
        let (mut a, mut b) = (strip(by_name), strip(file));
        a.path = Default::default();
        b.path = Default::default();
        assert!(a == b, "{name}: the shipped scene differs from its file");
    }
}

#[test]
fn resolve_prefers_a_file_and_names_the_shipped_scenes_otherwise() {
    // From a folder with no scene files, a bare name resolves to the shipped scene.
    let s = Scene::resolve("powder_transport").unwrap();
    assert_eq!(s.path, Path::new("scenes/powder_transport.ron"));
    // A path is a path: a missing file is an I/O error, not a lookup among shipped names.
    let missing = Scene::resolve("no/such/powder_transport.ron").unwrap_err();
    assert!(matches!(missing, SceneError::Io { .. }), "{missing}");
    // A bare name that is neither: one line, naming it and listing what is shipped.
    let e = Scene::resolve("powder_transprot").unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, SceneError::Unknown { .. }), "{msg}");
    assert!(!msg.contains('\n'), "{msg}");
    assert!(msg.starts_with("powder_transprot: "), "{msg}");
    for name in shipped::names() {
        assert!(msg.contains(name), "{msg} does not list {name}");
    }
}
