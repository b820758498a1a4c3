//! Pinhole cameras (OpenCV's convention: x right, y down, z forward; intrinsics in pixels) and
//! the camera file that names them.
//!
//! ```json
//! {"cameras": [{"name": "front", "width": 640, "height": 480,
//!               "fx": 600, "fy": 600, "cx": 320, "cy": 240,
//!               "position": [0.1, 0.12, 0.25], "look_at": [0.1, 0.02, 0.04], "up": [0, 1, 0]}]}
//! ```
//!
//! Instead of `look_at` and `up`, a camera may give `rotation`: the world-from-camera rotation as
//! a unit quaternion `[x, y, z, w]` (what a calibration toolbox's extrinsics give).

use glam::{DMat3, DQuat, DVec3};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// A camera as its file gives it.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
    pub name: String,
    pub width: u32,
    pub height: u32,
    /// Focal lengths in pixels.
    pub fx: f64,
    pub fy: f64,
    /// Principal point in pixels (default: the image centre).
    #[serde(default)]
    pub cx: Option<f64>,
    #[serde(default)]
    pub cy: Option<f64>,
    /// The optical centre in world coordinates (m).
    pub position: [f64; 3],
    /// A point the camera looks at (with `up`), or ...
    #[serde(default)]
    pub look_at: Option<[f64; 3]>,
    #[serde(default)]
    pub up: Option<[f64; 3]>,
    /// ... the world-from-camera rotation `[x, y, z, w]`.
    #[serde(default)]
    pub rotation: Option<[f64; 4]>,
}

/// A camera file: one or more cameras.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CameraFile {
    pub cameras: Vec<CameraSpec>,
}

/// A camera ready to cast rays and project points.
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    pub name: String,
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub position: DVec3,
    /// World from camera: columns are the camera's x (right), y (down) and z (forward) axes.
    pub rotation: DMat3,
}

/// The largest image side a camera may ask for: 8192 pixels (a 64-megapixel frame, 200 MB of
/// RGB), far above any demonstration camera, and a bound on what a typo can allocate.
pub const MAX_SIDE: u32 = 8192;

impl Camera {
    /// Checks a camera's fields: one line naming the field, its value and what is expected.
    pub fn from_spec(s: &CameraSpec) -> Result<Camera, String> {
        let field = |f: &str| format!("cameras['{}'].{f}", s.name);
        for (f, v) in [("width", s.width), ("height", s.height)] {
            if v == 0 || v > MAX_SIDE {
                return Err(format!(
                    "{} = {v}: expected 1 to {MAX_SIDE} pixels",
                    field(f)
                ));
            }
        }
        for (f, v) in [("fx", s.fx), ("fy", s.fy)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!(
                    "{} = {v}: expected a positive focal length in pixels",
                    field(f)
                ));
            }
        }
        let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
        if !finite(&s.position) {
            return Err(format!(
                "{} = {:?}: expected finite metres",
                field("position"),
                s.position
            ));
        }
        let position = DVec3::from(s.position);
        let rotation = match (s.look_at, s.rotation) {
            (Some(target), None) => {
                let up = DVec3::from(s.up.unwrap_or([0.0, 1.0, 0.0]));
                let z = (DVec3::from(target) - position).normalize_or_zero();
                let x = z.cross(up).normalize_or_zero();
                if !finite(&target) || z == DVec3::ZERO || x == DVec3::ZERO {
                    return Err(format!(
                        "{} = {target:?}: expected a point away from the position {:?}, not along `up` {:?}",
                        field("look_at"),
                        s.position,
                        up.to_array()
                    ));
                }
                DMat3::from_cols(x, z.cross(x), z)
            }
            (None, Some(q)) => {
                let quat = DQuat::from_array(q);
                if !finite(&q) || (quat.length() - 1.0).abs() > 1e-6 {
                    return Err(format!(
                        "{} = {q:?}: expected a unit quaternion [x, y, z, w]",
                        field("rotation")
                    ));
                }
                DMat3::from_quat(quat.normalize())
            }
            _ => {
                return Err(format!(
                    "{}: give either `look_at` (with an optional `up`) or `rotation`, not both or neither",
                    field("look_at")
                ))
            }
        };
        Ok(Camera {
            name: s.name.clone(),
            width: s.width,
            height: s.height,
            fx: s.fx,
            fy: s.fy,
            cx: s.cx.unwrap_or(0.5 * s.width as f64),
            cy: s.cy.unwrap_or(0.5 * s.height as f64),
            position,
            rotation,
        })
    }

    /// The unit direction (world) of the ray through the centre of pixel `(u, v)`.
    #[inline]
    pub fn ray(&self, u: u32, v: u32) -> DVec3 {
        let d = DVec3::new(
            (u as f64 + 0.5 - self.cx) / self.fx,
            (v as f64 + 0.5 - self.cy) / self.fy,
            1.0,
        );
        (self.rotation * d).normalize()
    }

    /// A world point in the camera's frame (z is the depth along the optical axis).
    #[inline]
    pub fn to_camera(&self, x: DVec3) -> DVec3 {
        self.rotation.transpose() * (x - self.position)
    }

    /// Pixel coordinates (continuous) of a point in the camera's frame with z > 0.
    #[inline]
    pub fn project(&self, c: DVec3) -> (f64, f64) {
        (self.fx * c.x / c.z + self.cx, self.fy * c.y / c.z + self.cy)
    }

    /// A camera that frames the box `[lo, hi]` from the front (+z, turned 20° towards +x) and above, 40° down, with a
    /// 45° vertical field of view: the default view of a scene.
    pub fn framing(name: &str, lo: DVec3, hi: DVec3, width: u32, height: u32) -> Camera {
        Camera::framing_at(name, lo, hi, width, height, 20.0)
    }

    /// [`Camera::framing`] from an azimuth of `azimuth_deg` (0: from +z, 90: from +x).
    pub fn framing_at(
        name: &str,
        lo: DVec3,
        hi: DVec3,
        width: u32,
        height: u32,
        azimuth_deg: f64,
    ) -> Camera {
        let centre = 0.5 * (lo + hi);
        let extent = (hi - lo).max_element().max(1e-6);
        let fov = 45f64.to_radians();
        let f = 0.5 * height as f64 / (0.5 * fov).tan();
        let (el, az) = (40f64.to_radians(), azimuth_deg.to_radians());
        let dir = DVec3::new(az.sin() * el.cos(), el.sin(), az.cos() * el.cos());
        let distance = 0.6 * extent / (0.5 * fov).tan();
        let spec = CameraSpec {
            name: name.into(),
            width,
            height,
            fx: f,
            fy: f,
            cx: None,
            cy: None,
            position: (centre + distance * dir).to_array(),
            look_at: Some(centre.to_array()),
            up: Some([0.0, 1.0, 0.0]),
            rotation: None,
        };
        Camera::from_spec(&spec).expect("a well-formed default camera")
    }
}

/// Reads a camera file; errors are one line naming the file and the field.
pub fn load(path: &Path) -> Result<Vec<Camera>, String> {
    let text = std::fs::read_to_string(path).map_err(|e| {
        format!(
            "{}: cannot read the camera file: {e}; check the path",
            path.display()
        )
    })?;
    let file: CameraFile = serde_json::from_str(&text).map_err(|e| {
        format!(
            "{}:{}:{}: {e}; a camera file is {{\"cameras\": [{{\"name\", \"width\", \"height\", \"fx\", \"fy\", \"position\", \"look_at\"}}]}}",
            path.display(),
            e.line(),
            e.column()
        )
    })?;
    if file.cameras.is_empty() {
        return Err(format!(
            "{}: field `cameras` is empty: give at least one camera",
            path.display()
        ));
    }
    let mut names = std::collections::BTreeSet::new();
    file.cameras
        .iter()
        .map(|c| {
            if !names.insert(c.name.as_str()) {
                return Err(format!(
                    "{}: field `cameras['{}'].name`: two cameras have this name; names make the frame files' names",
                    path.display(),
                    c.name
                ));
            }
            Camera::from_spec(c).map_err(|e| format!("{}: {e}", path.display()))
        })
        .collect()
}
