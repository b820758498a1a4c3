//! The scenes shipped with powderlab, compiled into the library so that they travel with every
//! build of it: the `powderlab` binary, embedders, and the Python wheel (where no `scenes/`
//! folder exists beside the installed package).
//!
//! [`Scene::shipped`] loads one by name; [`Scene::resolve`] takes a path or a shipped name, the
//! way the Python environments take their `scene` argument. `tests/shipped_scenes.rs` checks that
//! this table and the `scenes/` folder hold the same files.

use super::Scene;
use crate::error::SceneError;
use std::path::{Path, PathBuf};

/// Every `scenes/*.ron`, by name (the file name without `.ron`), in name order.
pub const SHIPPED: &[(&str, &str)] = &[
    (
        "calibration_collapse",
        include_str!("../../scenes/calibration_collapse.ron"),
    ),
    (
        "calibration_layers",
        include_str!("../../scenes/calibration_layers.ron"),
    ),
    (
        "calibration_slide",
        include_str!("../../scenes/calibration_slide.ron"),
    ),
    (
        "column_collapse_planar",
        include_str!("../../scenes/column_collapse_planar.ron"),
    ),
    ("free_fall", include_str!("../../scenes/free_fall.ron")),
    (
        "multi_scoop_dosing",
        include_str!("../../scenes/multi_scoop_dosing.ron"),
    ),
    ("plate_push", include_str!("../../scenes/plate_push.ron")),
    (
        "policy_dosing",
        include_str!("../../scenes/policy_dosing.ron"),
    ),
    (
        "policy_dosing_fine",
        include_str!("../../scenes/policy_dosing_fine.ron"),
    ),
    (
        "powder_transport",
        include_str!("../../scenes/powder_transport.ron"),
    ),
    (
        "powder_transport_dosing",
        include_str!("../../scenes/powder_transport_dosing.ron"),
    ),
    (
        "powder_transport_fine",
        include_str!("../../scenes/powder_transport_fine.ron"),
    ),
    (
        "precise_dosing",
        include_str!("../../scenes/precise_dosing.ron"),
    ),
    (
        "repose_cylinder",
        include_str!("../../scenes/repose_cylinder.ron"),
    ),
    ("sand_box", include_str!("../../scenes/sand_box.ron")),
    ("stiff_block", include_str!("../../scenes/stiff_block.ron")),
    ("vial_scale", include_str!("../../scenes/vial_scale.ron")),
    (
        "vial_weighing",
        include_str!("../../scenes/vial_weighing.ron"),
    ),
];

/// The names of the shipped scenes, in order.
pub fn names() -> impl Iterator<Item = &'static str> {
    SHIPPED.iter().map(|(name, _)| *name)
}

/// The text of the shipped scene `name`, if there is one.
pub fn text(name: &str) -> Option<&'static str> {
    SHIPPED
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, text)| *text)
}

impl Scene {
    /// The shipped scene `name` (for example `"powder_transport"`). Its `path` is the one it has
    /// in the repository, `scenes/NAME.ron`, so that messages name the file a user can open.
    pub fn shipped(name: &str) -> Result<Scene, SceneError> {
        match text(name) {
            Some(src) => Scene::parse(src, &PathBuf::from(format!("scenes/{name}.ron"))),
            None => Err(SceneError::Unknown {
                name: name.to_string(),
                shipped: names().collect::<Vec<_>>().join(", "),
            }),
        }
    }

    /// A scene from a path, or from a shipped scene's name when no such file exists and the
    /// argument is a bare name (no directory, no `.ron`). A file always wins over a shipped
    /// name, so a user's own `powder_transport` file is never shadowed.
    pub fn resolve(arg: impl AsRef<Path>) -> Result<Scene, SceneError> {
        let path = arg.as_ref();
        let bare = path.components().count() == 1 && path.extension().is_none();
        match path.to_str() {
            Some(name) if bare && !path.exists() => Scene::shipped(name),
            _ => Scene::load(path),
        }
    }
}
