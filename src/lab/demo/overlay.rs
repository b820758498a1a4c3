//! A Rerun recording of a fit over its demonstration (`demo fit` writes it beside fit.json):
//!
//! - `world/cameras/<name>`: each camera's pose and intrinsics (`Transform3D`, `Pinhole`), so
//!   the 3D view shows where it filmed from;
//! - `world/cameras/<name>/image`: the frame (when the demonstration has images);
//! - `world/cameras/<name>/track`: the tracked spoon's silhouette in a translucent green over it;
//! - `world/tracked_spoon`: the fitted spoon's mesh at the tracked pose.
//!
//! The timeline is `step`, each frame's global step. The file is written to `<path>.partial`
//! and renamed when complete.

use super::fit::Tracked;
use super::format::{read_png, Demo};
use crate::lab::render::silhouette::silhouette;
use crate::math::sdf::Shape;
use crate::util::partial_path;
use rerun::{Image, Mesh3D, Pinhole, Transform3D};
use std::path::Path;

/// The overlay's colour: green, half transparent.
const TRACK_RGBA: [u8; 4] = [40, 220, 90, 120];

/// Writes the recording of the track `fit` (its poses and fitted spoon) over `demo` to `path`.
pub fn write(path: &Path, demo: &Demo, fit: &Tracked) -> anyhow::Result<()> {
    let spoon = &fit.spoon;
    let rec = rerun::RecordingStreamBuilder::new("powderlab demo fit").save(partial_path(path))?;
    rec.log_static("world", &rerun::ViewCoordinates::RIGHT_HAND_Y_UP())?;
    for cam in &demo.cameras {
        let r = cam.rotation.as_mat3();
        rec.log_static(
            format!("world/cameras/{}", cam.name),
            &Transform3D::from_translation_mat3x3(cam.position.as_vec3().to_array(), r),
        )?;
        rec.log_static(
            format!("world/cameras/{}", cam.name),
            &Pinhole::new([
                [cam.fx as f32, 0.0, 0.0],
                [0.0, cam.fy as f32, 0.0],
                [cam.cx as f32, cam.cy as f32, 1.0],
            ])
            .with_resolution([cam.width as f32, cam.height as f32]),
        )?;
    }
    let mesh = Shape::from_spoon(spoon).mesh();
    rec.log_static(
        "world/tracked_spoon",
        &Mesh3D::new(mesh.vertices)
            .with_triangle_indices(mesh.triangles)
            .with_albedo_factor(rerun::Rgba32::from_unmultiplied_rgba(
                TRACK_RGBA[0],
                TRACK_RGBA[1],
                TRACK_RGBA[2],
                255,
            )),
    )?;
    for (((step, _), pose), images) in demo.frames.iter().zip(&fit.poses).zip(&demo.images) {
        rec.set_time_sequence("step", *step as i64);
        rec.log(
            "world/tracked_spoon",
            &Transform3D::from_translation_mat3x3(
                pose.translation.as_vec3().to_array(),
                glam::Mat3::from_quat(pose.rotation.as_quat()),
            ),
        )?;
        for (cam, image) in demo.cameras.iter().zip(images) {
            let size = [cam.width, cam.height];
            if let Some(file) = image {
                let (_, _, rgb) =
                    read_png(file).map_err(|e| anyhow::anyhow!("{}: {e}", file.display()))?;
                rec.log(
                    format!("world/cameras/{}/image", cam.name),
                    &Image::from_rgb24(rgb, size),
                )?;
            }
            let tau = 0.25 * (pose.translation - cam.position).length() / cam.fx;
            let rgba: Vec<u8> = silhouette(cam, spoon, pose, tau)
                .occupancy
                .iter()
                .flat_map(|&o| if o > 0.5 { TRACK_RGBA } else { [0; 4] })
                .collect();
            rec.log(
                format!("world/cameras/{}/track", cam.name),
                &Image::from_rgba32(rgba, size).with_draw_order(1.0),
            )?;
        }
    }
    rec.flush_blocking()?;
    drop(rec);
    std::fs::rename(partial_path(path), path)?;
    Ok(())
}
