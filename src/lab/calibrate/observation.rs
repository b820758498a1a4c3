//! Observations to calibrate from, read and written:
//!
//! - **a point cloud**, any PLY with a `vertex` element whose `x`, `y`, `z` are float or double
//!   (ASCII or binary: what `simulate --save-state`, Open3D or a depth-camera pipeline write);
//! - **a height map**, a CSV of heights in metres, one row per pixel row along z, one column
//!   per pixel along x, `nan` (or an empty field) where the camera saw nothing. Comment lines
//!   starting with `#` carry the grid: `# pixel=0.0025 origin_x=0.00125 origin_z=0.00125`
//!   (metres; the origin is pixel (0, 0)'s centre).
//!
//! - **a 16-bit PNG height map**, grey, one sample per pixel (row 0 at the smallest z), with
//!   text chunks `pixel`, `origin_x`, `origin_z` (metres, as in the CSV), `height_scale`
//!   (metres per unit) and optionally `height_offset` (metres, default 0): the height is
//!   `offset + scale·value`, and a value of 0 marks an unseen pixel (a depth camera's hole).
//!
//! Each is tied to a global step: `FILE@STEP`, or the scene's horizon without one. `BODY=FILE`
//! (a body's name, then `=`) compares it with that body's particles only: a coloured layer
//! segmented in a side camera's images, or a tracer. Every failure is one line naming the file
//! and what is wrong.

use crate::math::heightfield::HeightGrid;
use glam::DVec3;
use std::path::{Path, PathBuf};

/// The largest observation file read (bytes): a million-point binary cloud is about 12 MB, a
/// 4096² height map about 200 MB of text.
pub const MAX_OBSERVATION_BYTES: u64 = 1 << 30;

/// What was observed.
#[derive(Clone, Debug, PartialEq)]
pub enum Observation {
    /// Surface heights over a grid (m), NaN where unseen.
    Heights { grid: HeightGrid, heights: Vec<f64> },
    /// Points on or in the powder (m).
    Cloud(Vec<DVec3>),
}

/// An observation file and the global step it shows.
#[derive(Clone, Debug, PartialEq)]
pub struct Observed {
    pub path: PathBuf,
    /// `None`: the scene's horizon.
    pub step: Option<usize>,
    /// The body whose particles it shows (`None`: every body's).
    pub body: Option<String>,
    pub what: Observation,
}

impl Observation {
    pub fn kind(&self) -> &'static str {
        match self {
            Observation::Heights { .. } => "height map",
            Observation::Cloud(_) => "point cloud",
        }
    }
}

/// Parses `[BODY=]FILE[@STEP]` and reads the file. `BODY` is a scene's body name: letters,
/// digits, `_` and `-`.
pub fn read_arg(arg: &str) -> Result<Observed, String> {
    let (body, rest) = match arg.split_once('=') {
        Some((b, f))
            if !b.is_empty()
                && b.chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-') =>
        {
            (Some(b.to_string()), f)
        }
        _ => (None, arg),
    };
    let (file, step) = match rest.rsplit_once('@') {
        Some((f, s)) if !s.is_empty() && s.chars().all(|c| c.is_ascii_digit()) => (
            f,
            Some(s.parse::<usize>().map_err(|_| {
                format!(
                    "{arg}: the step after '@' is too large, expected a global step of the scene"
                )
            })?),
        ),
        _ => (rest, None),
    };
    let path = PathBuf::from(file);
    Ok(Observed {
        what: read(&path)?,
        path,
        step,
        body,
    })
}

/// Reads an observation by its extension (`.ply`, `.csv`).
pub fn read(path: &Path) -> Result<Observation, String> {
    let shown = path.display();
    let meta = std::fs::metadata(path).map_err(|e| format!("{shown}: cannot read it: {e}"))?;
    if meta.len() > MAX_OBSERVATION_BYTES {
        return Err(format!(
            "{shown}: {} bytes, over the {} the reader takes; downsample the observation",
            meta.len(),
            MAX_OBSERVATION_BYTES
        ));
    }
    let bytes = std::fs::read(path).map_err(|e| format!("{shown}: cannot read it: {e}"))?;
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase());
    match ext.as_deref() {
        Some("ply") => read_ply(&bytes).map_err(|e| format!("{shown}: {e}")),
        Some("csv") => read_csv(&bytes).map_err(|e| format!("{shown}: {e}")),
        Some("png") => read_png(&bytes).map_err(|e| format!("{shown}: {e}")),
        _ => Err(format!(
            "{shown}: unknown observation type; expected a point cloud (.ply) or a height map (.csv, or a 16-bit .png)"
        )),
    }
}

fn read_ply(bytes: &[u8]) -> Result<Observation, String> {
    use ply_rs_bw::parser::Parser;
    use ply_rs_bw::ply::{DefaultElement, Property};
    let ply = Parser::<DefaultElement>::new()
        .read_ply(&mut &bytes[..])
        .map_err(|e| format!("not a PLY file this reader understands: {e}"))?;
    let vertices = ply
        .payload
        .get("vertex")
        .ok_or("the PLY has no 'vertex' element; expected points with x, y, z")?;
    if vertices.is_empty() {
        return Err("the PLY has no vertices; expected at least one observed point".into());
    }
    let coord = |v: &DefaultElement, k: &str, i: usize| -> Result<f64, String> {
        match v.get(k) {
            Some(Property::Float(f)) => Ok(*f as f64),
            Some(Property::Double(f)) => Ok(*f),
            Some(_) => Err(format!(
                "vertex property '{k}' is not a float or double; expected coordinates in metres"
            )),
            None => Err(format!("vertex {i} has no '{k}'; expected x, y and z")),
        }
    };
    let mut pts = Vec::with_capacity(vertices.len());
    for (i, v) in vertices.iter().enumerate() {
        let p = DVec3::new(coord(v, "x", i)?, coord(v, "y", i)?, coord(v, "z", i)?);
        if !p.is_finite() {
            return Err(format!(
                "vertex {i} is not finite ({p}); remove the invalid points (a depth camera's holes) first"
            ));
        }
        pts.push(p);
    }
    Ok(Observation::Cloud(pts))
}

fn read_csv(bytes: &[u8]) -> Result<Observation, String> {
    let text = std::str::from_utf8(bytes).map_err(|e| {
        format!(
            "not UTF-8 text at byte {}; expected a CSV height map",
            e.valid_up_to()
        )
    })?;
    let (mut pixel, mut ox, mut oz) = (None, None, None);
    let mut rows: Vec<Vec<f64>> = Vec::new();
    for (ln, line) in text.lines().enumerate() {
        let line = line.trim();
        if let Some(c) = line.strip_prefix('#') {
            for tok in c.split_whitespace() {
                if let Some((k, v)) = tok.split_once('=') {
                    let slot = match k {
                        "pixel" => &mut pixel,
                        "origin_x" => &mut ox,
                        "origin_z" => &mut oz,
                        _ => continue,
                    };
                    let x: f64 = v.parse().map_err(|_| {
                        format!("line {}: {k}={v} is not a number (metres)", ln + 1)
                    })?;
                    *slot = Some(x);
                }
            }
            continue;
        }
        if line.is_empty() {
            continue;
        }
        let row = line
            .split(',')
            .enumerate()
            .map(|(col, f)| {
                let f = f.trim();
                if f.is_empty() || f.eq_ignore_ascii_case("nan") {
                    return Ok(f64::NAN);
                }
                match f.parse::<f64>() {
                    Ok(v) if v.is_finite() => Ok(v),
                    _ => Err(format!(
                        "line {}, column {}: '{}' is not a height in metres (use nan for an unseen pixel)",
                        ln + 1,
                        col + 1,
                        crate::scene::parse::bounded(f)
                    )),
                }
            })
            .collect::<Result<Vec<f64>, String>>()?;
        if let Some(first) = rows.first() {
            if row.len() != first.len() {
                return Err(format!(
                    "line {}: {} values, but the first row has {}; every row needs one per pixel along x",
                    ln + 1,
                    row.len(),
                    first.len()
                ));
            }
        }
        rows.push(row);
    }
    let need = |v: Option<f64>, k: &str| {
        v.ok_or_else(|| {
            format!("no '{k}=' in a '#' line; the grid needs '# pixel=P origin_x=X origin_z=Z' (metres)")
        })
    };
    let (pixel, ox, oz) = (
        need(pixel, "pixel")?,
        need(ox, "origin_x")?,
        need(oz, "origin_z")?,
    );
    if !(pixel.is_finite() && pixel > 0.0) {
        return Err(format!("pixel={pixel} must be a positive length in metres"));
    }
    if !(ox.is_finite() && oz.is_finite()) {
        return Err("origin_x and origin_z must be finite (metres)".into());
    }
    if rows.is_empty() {
        return Err("no rows of heights; expected one row per pixel row along z".into());
    }
    let nx = rows[0].len();
    let heights: Vec<f64> = rows.concat();
    if heights.iter().all(|h| h.is_nan()) {
        return Err("every pixel is nan; the map shows nothing to calibrate against".into());
    }
    Ok(Observation::Heights {
        grid: HeightGrid {
            origin: [ox, oz],
            pixel,
            nx,
            nz: rows.len(),
        },
        heights,
    })
}

/// The grid keys of a PNG height map (see the module docs).
const PNG_KEYS: [&str; 5] = [
    "pixel",
    "origin_x",
    "origin_z",
    "height_scale",
    "height_offset",
];

fn read_png(bytes: &[u8]) -> Result<Observation, String> {
    let decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    let mut reader = decoder
        .read_info()
        .map_err(|e| format!("not a PNG this reader understands: {e}"))?;
    let mut keys = [None; 5];
    for t in &reader.info().uncompressed_latin1_text {
        if let Some(k) = PNG_KEYS.iter().position(|k| *k == t.keyword) {
            let v: f64 = t.text.trim().parse().map_err(|_| {
                format!(
                    "text chunk {}={} is not a number (metres)",
                    t.keyword,
                    crate::scene::parse::bounded(&t.text)
                )
            })?;
            keys[k] = Some(v);
        }
    }
    let need = |k: usize| {
        keys[k].filter(|v| v.is_finite()).ok_or_else(|| {
            format!(
                "no finite '{}' text chunk; a PNG height map needs pixel, origin_x, origin_z and height_scale (metres)",
                PNG_KEYS[k]
            )
        })
    };
    let (pixel, ox, oz, scale) = (need(0)?, need(1)?, need(2)?, need(3)?);
    let offset = keys[4].unwrap_or(0.0);
    if !(pixel > 0.0 && scale > 0.0 && offset.is_finite()) {
        return Err(format!(
            "pixel={pixel} and height_scale={scale} must be positive, height_offset={offset} finite"
        ));
    }
    let size = reader
        .output_buffer_size()
        .ok_or("the image is too large for this machine")?;
    let mut buf = vec![0u8; size];
    let info = reader
        .next_frame(&mut buf)
        .map_err(|e| format!("cannot decode the image: {e}"))?;
    if info.color_type != png::ColorType::Grayscale || info.bit_depth != png::BitDepth::Sixteen {
        return Err(format!(
            "{:?} at {:?} bits; a height map is 16-bit greyscale, one height per pixel",
            info.color_type, info.bit_depth
        ));
    }
    let heights: Vec<f64> = buf[..info.buffer_size()]
        .chunks_exact(2)
        .map(|c| match u16::from_be_bytes([c[0], c[1]]) {
            0 => f64::NAN,
            v => offset + scale * v as f64,
        })
        .collect();
    if heights.iter().all(|h| h.is_nan()) {
        return Err("every pixel is 0 (unseen); the map shows nothing to calibrate against".into());
    }
    Ok(Observation::Heights {
        grid: HeightGrid {
            origin: [ox, oz],
            pixel,
            nx: info.width as usize,
            nz: info.height as usize,
        },
        heights,
    })
}

/// A 16-bit greyscale PNG of a height map (see the module docs) at `scale` metres per unit
/// from `offset`; unseen pixels, and heights below `offset + scale/2`, are written as 0.
pub fn heights_png(grid: &HeightGrid, heights: &[f64], offset: f64, scale: f64) -> Vec<u8> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, grid.nx as u32, grid.nz as u32);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Sixteen);
        let values = [grid.pixel, grid.origin[0], grid.origin[1], scale, offset];
        for (k, v) in PNG_KEYS.iter().zip(values) {
            enc.add_text_chunk(k.to_string(), format!("{v:e}"))
                .expect("ASCII keywords under 80 bytes");
        }
        let data: Vec<u8> = heights
            .iter()
            .flat_map(|h| {
                let v = if h.is_finite() {
                    ((h - offset) / scale).round().clamp(0.0, 65535.0) as u16
                } else {
                    0
                };
                v.to_be_bytes()
            })
            .collect();
        let mut w = enc.write_header().expect("writing to memory");
        w.write_image_data(&data).expect("writing to memory");
    }
    out
}

/// The CSV text of a height map (see the module docs), heights to the micrometre.
pub fn heights_csv(grid: &HeightGrid, heights: &[f64]) -> String {
    let mut s = format!(
        "# powderlab height map: heights in metres, rows along z, columns along x, nan unseen\n# pixel={} origin_x={} origin_z={}\n",
        grid.pixel, grid.origin[0], grid.origin[1]
    );
    for row in heights.chunks(grid.nx) {
        let cells: Vec<String> = row
            .iter()
            .map(|h| {
                if h.is_finite() {
                    format!("{h:.6}")
                } else {
                    "nan".into()
                }
            })
            .collect();
        s.push_str(&cells.join(","));
        s.push('\n');
    }
    s
}

/// A binary PLY of points as float x, y, z: the layout of a depth camera's cloud.
pub fn cloud_ply(points: &[DVec3]) -> Vec<u8> {
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\ncomment powderlab observation\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nend_header\n",
        points.len()
    )
    .into_bytes();
    for p in points {
        for c in [p.x, p.y, p.z] {
            out.extend_from_slice(&(c as f32).to_le_bytes());
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmp(name: &str, bytes: &[u8]) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("powderlab-obs-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    }

    /// The grid and heights of a height-map file.
    fn read_heights(p: &Path) -> (HeightGrid, Vec<f64>) {
        match read(p).unwrap() {
            Observation::Heights { grid, heights } => (grid, heights),
            Observation::Cloud(_) => panic!("{}: a height map", p.display()),
        }
    }

    #[test]
    fn a_body_prefix_and_a_step_suffix_are_read_off_the_argument() {
        let p = tmp("cloud.ply", &cloud_ply(&[DVec3::new(0.01, 0.02, 0.03)]));
        let o = read_arg(&format!("bed-1={}@40", p.display())).unwrap();
        assert_eq!(
            (o.body.as_deref(), o.step, o.path.as_path()),
            (Some("bed-1"), Some(40), p.as_path())
        );
        let o = read_arg(&p.display().to_string()).unwrap();
        assert_eq!((o.body, o.step), (None, None));
        // An '=' inside a folder name is part of the path, not a body.
        let e = read_arg("runs/a=b/none.ply@3").unwrap_err();
        assert!(e.contains("runs/a=b/none.ply"), "{e}");
    }

    #[test]
    fn height_maps_and_clouds_round_trip() {
        let grid = HeightGrid {
            origin: [0.001, -0.002],
            pixel: 0.0025,
            nx: 3,
            nz: 2,
        };
        let h = vec![0.01, f64::NAN, 0.012345, 0.0, 0.02, 0.03];
        let p = tmp("h.csv", heights_csv(&grid, &h).as_bytes());
        let (g2, h2) = read_heights(&p);
        assert_eq!(g2, grid);
        for (a, b) in h.iter().zip(&h2) {
            assert!((a.is_nan() && b.is_nan()) || (a - b).abs() < 1e-9);
        }
        let pts = vec![DVec3::new(0.5, 0.25, -0.125), DVec3::new(1.0, 2.0, 3.0)];
        let q = tmp("c.ply", &cloud_ply(&pts));
        assert_eq!(read(&q).unwrap(), Observation::Cloud(pts));
        // A PNG at 10 µm per unit from 0: every height back within half a unit; the unseen one, and
        // the height 0 (below half a unit, written as a hole), read unseen.
        let r = tmp("h.png", &heights_png(&grid, &h, 0.0, 1e-5));
        let (g3, h3) = read_heights(&r);
        assert_eq!(g3, grid);
        for (a, b) in h.iter().zip(&h3) {
            assert!(
                (a.is_nan() && b.is_nan()) || (a - b).abs() <= 0.5e-5 + 1e-15 || *a == 0.0,
                "{a} {b}"
            );
        }
    }

    #[test]
    fn bad_observations_get_one_line_naming_the_file() {
        let cases: [(&str, &[u8], &str); 7] = [
            ("a.csv", b"0.1,0.2\n", "no 'pixel='"),
            (
                "b.csv",
                b"# pixel=0.01 origin_x=0 origin_z=0\n0.1,0.2\n0.3\n",
                "line 3: 1 values",
            ),
            (
                "c.csv",
                b"# pixel=0.01 origin_x=0 origin_z=0\n0.1,x\n",
                "line 2, column 2",
            ),
            (
                "d.ply",
                b"ply\nformat ascii 1.0\nelement face 0\nend_header\n",
                "no 'vertex'",
            ),
            ("e.xyz", b"1 2 3\n", "unknown observation type"),
            (
                "f.csv",
                b"# pixel=-1 origin_x=0 origin_z=0\n0.1\n",
                "pixel=-1",
            ),
            ("g.png", b"\x89PNG\r\n\x1a\nnot really", "not a PNG"),
        ];
        for (name, bytes, want) in cases {
            let p = tmp(name, bytes);
            let e = read(&p).unwrap_err();
            assert!(e.contains(name) && e.contains(want), "{name}: {e}");
            assert!(!e.contains('\n'), "{e}");
        }
        let e = read_arg("/nonexistent/obs.ply@7").unwrap_err();
        assert!(
            e.contains("/nonexistent/obs.ply") && e.contains("cannot read"),
            "{e}"
        );
    }
}
