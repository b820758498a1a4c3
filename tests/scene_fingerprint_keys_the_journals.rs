//! Journals are keyed by what fixes a result: `Scene::fingerprint` ignores the text (comments,
//! layout, a default written out) and changes with any value.

use powderlab::scene::Scene;
use std::path::Path;

#[test]
fn a_comment_keeps_the_fingerprint_and_a_value_changes_it() {
    let text = powderlab::scene::shipped::text("powder_transport").unwrap();
    let base = Scene::parse(text, Path::new("a.ron")).unwrap();
    let commented = format!("// a note added by hand\n{}\n\n// and another\n", text);
    let same = Scene::parse(&commented, Path::new("b.ron")).unwrap();
    assert_ne!(base.source, same.source);
    assert_eq!(base.fingerprint(), same.fingerprint());
    // The scene written out with every default spelled is the same scene.
    let spelled = ron::ser::to_string_pretty(&base, Default::default()).unwrap();
    let spelled = Scene::parse(&spelled, Path::new("c.ron")).unwrap();
    assert_eq!(base.fingerprint(), spelled.fingerprint());
    // A changed value is another scene.
    let mut other = base.clone();
    other.simulation.gravity.1 -= 1e-9;
    assert_ne!(base.fingerprint(), other.fingerprint());
    // The SVD's precision, added after journals were kept: at its default it leaves the
    // fingerprint as it was (the value below is the scene's from before the setting); F32 is
    // another scene.
    assert_eq!(base.fingerprint(), FINGERPRINT_BEFORE_THE_SVD_SETTING);
    let mut f32_svd = base.clone();
    f32_svd.simulation.svd = powderlab::components::Precision::F32;
    assert_ne!(base.fingerprint(), f32_svd.fingerprint());
}

/// `powder_transport`'s fingerprint at the commit before `simulation.svd` existed.
const FINGERPRINT_BEFORE_THE_SVD_SETTING: &str = "2b59c1472115a7b4";
