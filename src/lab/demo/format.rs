//! The demonstration format: a folder with `demo.json`, the frames as PNG files and optional
//! masks.
//!
//! ```json
//! {"fps": 100.0,
//!  "cameras": [{"name": "front", "width": 96, "height": 72, "fx": 90, "fy": 90,
//!               "position": [0.1, 0.1, 0.2], "look_at": [0.1, 0.02, 0.04]}],
//!  "key_colour": [217, 64, 51],
//!  "frames": [{"index": 0, "images": {"front": "front_00000.png"},
//!              "masks": {"front": "front_00000_mask.png"}}]}
//! ```
//!
//! Cameras are in the scene's frame (metres), as `powderlab render` takes them. A frame's time
//! is `index / fps`. A mask is a greyscale or RGB PNG: the spoon where it is 192 or brighter,
//! background below 64, and unknown between (a pixel whose occluder, such as powder, may hide
//! the spoon: the tracker ignores it);
//! a frame without a mask is segmented by `key_colour`, the spoon's colour in the images: a
//! pixel is the spoon where its chromaticity is within [`KEY_CHROMA`] of the key's and it is not
//! dark. Seed B segments with SAM; no model weights can be fetched here, so masks from any
//! segmenter are the way in for real video.

use crate::lab::render::camera::{Camera, CameraSpec};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The largest chromaticity distance (in `r/(r+g+b)`, `g/(r+g+b)`) of a key-coloured pixel:
/// shading scales a colour's brightness, not its chromaticity, and 0.08 separates a saturated
/// key from grey steel, sand and the glass.
pub const KEY_CHROMA: f64 = 0.08;

/// One frame in `demo.json`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct FrameSpec {
    pub index: usize,
    /// Image file per camera name, relative to the folder.
    pub images: BTreeMap<String, String>,
    #[serde(default)]
    pub masks: BTreeMap<String, String>,
}

/// `demo.json`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DemoSpec {
    pub fps: f64,
    pub cameras: Vec<CameraSpec>,
    #[serde(default)]
    pub key_colour: Option<[u8; 3]>,
    pub frames: Vec<FrameSpec>,
}

/// A loaded demonstration: its cameras and, per frame, the spoon's mask in each view (0 or 1,
/// row-major), in the cameras' order.
pub struct Demo {
    pub dir: PathBuf,
    pub fps: f64,
    pub cameras: Vec<Camera>,
    pub frames: Vec<(usize, Vec<Vec<f64>>)>,
    /// Each frame's image file from each camera, where it has one.
    pub images: Vec<Vec<Option<PathBuf>>>,
}

/// Reads an 8-bit PNG as RGB (greyscale is repeated); `None` with the decoder's complaint.
pub fn read_png(path: &Path) -> Result<(u32, u32, Vec<u8>), String> {
    let file = std::fs::File::open(path).map_err(|e| format!("cannot read it: {e}"))?;
    let mut decoder = png::Decoder::new(std::io::BufReader::new(file));
    decoder.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut reader = decoder.read_info().map_err(|e| format!("not a PNG: {e}"))?;
    let mut buf = vec![0; reader.output_buffer_size().ok_or("too large an image")?];
    let info = reader
        .next_frame(&mut buf)
        .map_err(|e| format!("not a PNG: {e}"))?;
    let (w, h) = (info.width, info.height);
    let n = (w * h) as usize;
    let rgb = match info.color_type {
        png::ColorType::Grayscale => buf[..n].iter().flat_map(|&g| [g, g, g]).collect(),
        png::ColorType::GrayscaleAlpha => buf[..2 * n]
            .chunks(2)
            .flat_map(|c| [c[0], c[0], c[0]])
            .collect(),
        png::ColorType::Rgb => buf[..3 * n].to_vec(),
        png::ColorType::Rgba => buf[..4 * n]
            .chunks(4)
            .flat_map(|c| [c[0], c[1], c[2]])
            .collect(),
        png::ColorType::Indexed => return Err("an indexed PNG that did not expand".into()),
    };
    Ok((w, h, rgb))
}

/// The spoon's mask from an image by its key colour.
pub fn key_mask(rgb: &[u8], key: [u8; 3]) -> Vec<f64> {
    let chroma = |c: [f64; 3]| {
        let s = (c[0] + c[1] + c[2]).max(1e-9);
        (c[0] / s, c[1] / s)
    };
    let k = chroma(key.map(f64::from));
    rgb.chunks(3)
        .map(|p| {
            let c = [p[0], p[1], p[2]].map(f64::from);
            let (r, g) = chroma(c);
            let near = (r - k.0).hypot(g - k.1) < KEY_CHROMA;
            if near && c.iter().sum::<f64>() > 60.0 {
                1.0
            } else {
                0.0
            }
        })
        .collect()
}

/// Loads a demonstration folder; errors are one line naming the file and the field.
pub fn load(dir: &Path) -> Result<Demo, String> {
    let json = dir.join("demo.json");
    let text = std::fs::read_to_string(&json).map_err(|e| {
        format!(
            "{}: cannot read the demonstration: {e}; a demonstration is a folder with demo.json and its frames",
            json.display()
        )
    })?;
    let spec: DemoSpec = serde_json::from_str(&text).map_err(|e| {
        format!(
            "{}:{}:{}: {e}; see src/lab/demo/format.rs for the fields",
            json.display(),
            e.line(),
            e.column()
        )
    })?;
    let at = |field: String, what: String| format!("{}: field `{field}`: {what}", json.display());
    if !(spec.fps.is_finite() && spec.fps > 0.0) {
        return Err(at(
            "fps".into(),
            format!("{} is not a positive frame rate", spec.fps),
        ));
    }
    if spec.cameras.is_empty() || spec.frames.is_empty() {
        return Err(at(
            if spec.cameras.is_empty() {
                "cameras"
            } else {
                "frames"
            }
            .into(),
            "is empty: give at least one".into(),
        ));
    }
    let cameras = spec
        .cameras
        .iter()
        .map(Camera::from_spec)
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| format!("{}: {e}", json.display()))?;
    let mut frames = Vec::new();
    let images = spec
        .frames
        .iter()
        .map(|frame| {
            cameras
                .iter()
                .map(|c| frame.images.get(&c.name).map(|i| dir.join(i)))
                .collect()
        })
        .collect();
    for (f, frame) in spec.frames.iter().enumerate() {
        let mut views = Vec::new();
        for cam in &cameras {
            let field = |kind: &str| format!("frames[{f}].{kind}.{}", cam.name);
            let (file, is_mask) = match (frame.masks.get(&cam.name), frame.images.get(&cam.name)) {
                (Some(m), _) => (m, true),
                (None, Some(i)) => (i, false),
                (None, None) => {
                    return Err(at(
                        field("images"),
                        "missing: every frame needs an image or a mask from every camera".into(),
                    ))
                }
            };
            let kind = if is_mask { "masks" } else { "images" };
            let (w, h, rgb) =
                read_png(&dir.join(file)).map_err(|e| at(field(kind), format!("{file}: {e}")))?;
            if (w, h) != (cam.width, cam.height) {
                return Err(at(
                    field(kind),
                    format!(
                        "{file} is {w}×{h}, but camera '{}' is {}×{}",
                        cam.name, cam.width, cam.height
                    ),
                ));
            }
            let mask = if is_mask {
                rgb.chunks(3)
                    .map(|p| match p[0] {
                        192.. => 1.0,
                        64..=191 => f64::NAN,
                        _ => 0.0,
                    })
                    .collect()
            } else {
                let key = spec.key_colour.ok_or_else(|| {
                    at(
                        field("masks"),
                        "missing, and no `key_colour` to segment the image by: give masks or the spoon's colour".into(),
                    )
                })?;
                key_mask(&rgb, key)
            };
            views.push(mask);
        }
        frames.push((frame.index, views));
    }
    Ok(Demo {
        dir: dir.to_path_buf(),
        fps: spec.fps,
        cameras,
        frames,
        images,
    })
}
