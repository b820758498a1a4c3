//! Reading a scene file, and locating an error's field in its text (line and column).

use super::Scene;
use crate::error::{FieldError, SceneError};
use std::path::Path;

impl Scene {
    /// Reads, parses and validates a scene file.
    pub fn load(path: impl AsRef<Path>) -> Result<Scene, SceneError> {
        let path = path.as_ref();
        let bytes = std::fs::read(path).map_err(|cause| SceneError::Io {
            file: path.to_path_buf(),
            cause,
        })?;
        Self::parse_bytes(&bytes, path)
    }

    /// Parses and validates the bytes of a scene file: text that is not UTF-8 is refused with
    /// the line, column and byte offset of its first invalid byte.
    pub fn parse_bytes(bytes: &[u8], path: &Path) -> Result<Scene, SceneError> {
        match std::str::from_utf8(bytes) {
            Ok(src) => Self::parse(src, path),
            Err(e) => {
                let at = e.valid_up_to();
                let good = std::str::from_utf8(&bytes[..at]).expect("valid up to `at`");
                let (line, col) = line_col(good, at);
                Err(SceneError::Parse {
                    file: path.to_path_buf(),
                    line,
                    col,
                    message: format!(
                        "field `{}`: byte {at} (0x{:02X}) is not UTF-8: scene files are UTF-8 text",
                        bounded(&enclosing_field(good, at).unwrap_or_else(|| "Scene".into())),
                        bytes[at]
                    ),
                })
            }
        }
    }

    /// Parses and validates scene text; `path` is used in messages.
    pub fn parse(src: &str, path: &Path) -> Result<Scene, SceneError> {
        let mut scene: Scene = ron::Options::default()
            .with_default_extension(ron::extensions::Extensions::IMPLICIT_SOME)
            .from_str(src)
            .map_err(|e| {
                let (line, col) = (e.span.start.line, e.span.start.col);
                // ron names the problem but not the field ("Integer is out of bounds").
                // (A `name:` before the position on its line is the innermost key, so the
                // enclosing path always includes it.)
                let field = enclosing_field(src, offset_of(src, line, col))
                    .unwrap_or_else(|| "Scene".into());
                SceneError::Parse {
                    file: path.to_path_buf(),
                    line,
                    col,
                    message: format!(
                        "field `{}`: {}",
                        bounded(&field),
                        bounded(&e.code.to_string())
                    ),
                }
            })?;
        scene.path = path.to_path_buf();
        scene.source = src.to_string();
        scene.validate()?;
        Ok(scene)
    }

    /// Turns a field error into a located scene error.
    pub fn field_error(&self, e: FieldError) -> SceneError {
        let (line, col) = locate(&self.source, &e.field);
        SceneError::Invalid {
            file: self.path.clone(),
            line,
            col,
            field: bounded(&e.field),
            value: bounded(&e.value),
            // What is expected is the program's text, with a value or a name in it at most.
            expected: bounded_to(&e.expected, 6 * MAX_ECHO),
        }
    }
}

/// Longest name or value an error message repeats, in characters.
pub const MAX_ECHO: usize = 80;

/// `text` with every run of name characters longer than [`MAX_ECHO`] cut to its start and a
/// count, control characters escaped (`\n`: a name or value taken from a damaged file can
/// span lines, and a refusal is one line), and the whole cut at four times that: a 10 MB field
/// name is not echoed to stderr.
pub fn bounded(text: &str) -> String {
    bounded_to(text, 4 * MAX_ECHO)
}

/// [`bounded`] with the whole cut at `total` characters.
fn bounded_to(text: &str, total: usize) -> String {
    let mut out = String::new();
    let mut run = 0usize;
    let mut cut = 0usize;
    for c in text.chars() {
        if c.is_alphanumeric() || c == '_' {
            run += 1;
            if run > MAX_ECHO {
                cut += 1;
                continue;
            }
        } else {
            if cut > 0 {
                out.push_str(&format!("… ({} characters)", run));
                cut = 0;
            }
            run = 0;
        }
        if c.is_control() {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    if cut > 0 {
        out.push_str(&format!("… ({} characters)", run));
    }
    if out.chars().count() > total {
        out = out.chars().take(total).collect::<String>() + "…";
    }
    out
}

/// Byte offset of 1-based `line`, `col` (in characters) in `src`, clamped to its end.
fn offset_of(src: &str, line: usize, col: usize) -> usize {
    let mut off = 0;
    for (i, l) in src.split_inclusive('\n').enumerate() {
        if i + 1 == line {
            return off
                + l.char_indices()
                    .nth(col.saturating_sub(1))
                    .map_or(l.len(), |(b, _)| b);
        }
        off += l.len();
    }
    src.len()
}

/// The dotted path of the field whose value holds byte `offset` of `src`, such as
/// `simulation.cells` or `colliders[2].shape`: the keys (`name:` or `"name":`) of the brackets
/// open at `offset`, with list items as `[i]`. `None` at the top level.
pub fn enclosing_field(src: &str, offset: usize) -> Option<String> {
    struct Frame {
        list: bool,
        index: usize,
        key: Option<String>,
    }
    let mut frames = vec![Frame {
        list: false,
        index: 0,
        key: None,
    }];
    let b = src.as_bytes();
    let end = offset.min(b.len());
    let mut i = 0;
    // The last word or string, a key if a `:` follows it.
    let mut word: Option<String> = None;
    while i < end {
        let c = b[i];
        match c {
            b'/' if b.get(i + 1) == Some(&b'/') => {
                while i < end && b[i] != b'\n' {
                    i += 1;
                }
                continue;
            }
            b'"' => {
                let start = i + 1;
                i += 1;
                while i < end && b[i] != b'"' {
                    i += if b[i] == b'\\' { 2 } else { 1 };
                }
                word = src.get(start..i.min(end)).map(str::to_string);
            }
            b':' => {
                if let (Some(w), Some(f)) = (word.take(), frames.last_mut()) {
                    f.key = Some(w);
                }
            }
            b'(' | b'[' | b'{' => {
                frames.push(Frame {
                    list: c == b'[',
                    index: 0,
                    key: None,
                });
                word = None;
            }
            b')' | b']' | b'}' => {
                if frames.len() > 1 {
                    frames.pop();
                }
                word = None;
            }
            b',' => {
                if let Some(f) = frames.last_mut() {
                    if f.list {
                        f.index += 1;
                    } else {
                        f.key = None;
                    }
                }
                word = None;
            }
            c if c.is_ascii_alphanumeric() || c == b'_' => {
                let start = i;
                while i < end && (b[i].is_ascii_alphanumeric() || b[i] == b'_') {
                    i += 1;
                }
                word = Some(src[start..i].to_string());
                continue;
            }
            _ => {}
        }
        i += 1;
    }
    let mut path = String::new();
    for (k, f) in frames.iter().enumerate() {
        // A list's index belongs to the key of the frame that opened it.
        if f.list && k > 0 {
            path.push_str(&format!("[{}]", f.index));
        }
        if let Some(key) = &f.key {
            if !path.is_empty() {
                path.push('.');
            }
            path.push_str(key);
        }
    }
    (!path.is_empty()).then_some(path)
}

/// Line and column (1-based) of a dotted field path such as `colliders[1].shape.radius` in RON
/// text: each key is searched after the previous one; `name[i]` skips to the i-th item of the
/// list that follows `name`. Falls back to the deepest key found.
pub fn locate(src: &str, path: &str) -> (usize, usize) {
    let mut offset = 0usize;
    for part in path.split('.') {
        let (key, index) = match part.find('[') {
            Some(b) => (
                &part[..b],
                part[b + 1..part.len() - 1].parse::<usize>().ok(),
            ),
            None => (part, None),
        };
        if let Some(p) = find_key(src, offset, key) {
            offset = p;
            if let Some(i) = index {
                if let Some(p) = nth_list_item(src, offset, i) {
                    offset = p;
                }
            }
        }
    }
    line_col(src, offset)
}

/// Line and column (1-based, the column in bytes) of byte `offset` of `src`.
fn line_col(src: &str, offset: usize) -> (usize, usize) {
    let before = &src[..offset];
    let line = before.matches('\n').count() + 1;
    let col = before.len() - before.rfind('\n').map_or(0, |p| p + 1) + 1;
    (line, col)
}

/// Offset of `key` used as a field name (`key:`) or map key (`"key":`) at or after `from`,
/// skipping comments.
fn find_key(src: &str, from: usize, key: &str) -> Option<usize> {
    let bytes = src.as_bytes();
    let mut i = from;
    while i < src.len() {
        if src[i..].starts_with("//") {
            i += src[i..].find('\n').unwrap_or(src.len() - i);
            continue;
        }
        let quoted = src[i..].starts_with('"')
            && src[i + 1..].starts_with(key)
            && src[i + 1 + key.len()..].starts_with('"');
        let bare = src[i..].starts_with(key)
            && (i == 0 || !(bytes[i - 1].is_ascii_alphanumeric() || bytes[i - 1] == b'_'));
        if quoted || bare {
            let end = i + key.len() + if quoted { 2 } else { 0 };
            let rest = src[end..].trim_start();
            if rest.starts_with(':') {
                return Some(i);
            }
        }
        i += src[i..].chars().next().map_or(1, |c| c.len_utf8());
    }
    None
}

/// Offset of the i-th top-level item of the `[...]` list starting after `from`.
fn nth_list_item(src: &str, from: usize, n: usize) -> Option<usize> {
    // The list (or tuple) opens right after the key's colon, or the path is not about it.
    let after = from + src[from..].find(':')? + 1;
    let open = after + src[after..].find(|c: char| !c.is_whitespace())?;
    if !src[open..].starts_with(['[', '(']) {
        return None;
    }
    let start = open + 1;
    let mut depth = 0i32;
    let mut item = 0usize;
    let mut at_item_start = true;
    for (k, ch) in src[start..].char_indices() {
        let p = start + k;
        if at_item_start && !ch.is_whitespace() {
            if item == n {
                return Some(p);
            }
            at_item_start = false;
        }
        match ch {
            '(' | '[' | '{' => depth += 1,
            '}' => depth -= 1,
            ']' | ')' => {
                if depth == 0 {
                    return None;
                }
                depth -= 1;
            }
            ',' if depth == 0 => {
                item += 1;
                at_item_start = true;
            }
            _ => {}
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_enclosing_field_is_the_path_of_keys_and_list_items() {
        let src = "Scene(simulation: (dx: 0.005, cells: (24, X, 24)), bodies: [(name: \"a\"), (fill: Box(min: (0, 0, X)))], materials: {\"sand\": DP((density: X))})";
        let at = |n: usize| {
            let off = src.match_indices('X').nth(n).unwrap().0;
            enclosing_field(src, off)
        };
        assert_eq!(at(0).as_deref(), Some("simulation.cells"));
        assert_eq!(at(1).as_deref(), Some("bodies[1].fill.min"));
        assert_eq!(at(2).as_deref(), Some("materials.sand.density"));
        assert_eq!(enclosing_field(src, 0), None);
    }

    #[test]
    fn a_long_name_is_cut_with_its_length() {
        let long = "a".repeat(10_000);
        let cut = bounded(&format!("Unexpected field named `{long}` in `Scene`"));
        assert!(cut.len() < 200, "{cut}");
        assert!(
            cut.contains("(10000 characters)") && cut.ends_with("in `Scene`"),
            "{cut}"
        );
        assert_eq!(bounded("field `dx`"), "field `dx`");
        // Found by the AFL++ target: a name taken from a damaged file ran into a comment on the
        // next line, and the refusal took two lines.
        assert_eq!(
            bounded("materials.a\n// sand.poisson_ratio"),
            "materials.a\\n// sand.poisson_ratio"
        );
        assert_eq!(bounded("a\r\tb\u{1b}"), "a\\r\\tb\\u{1b}");
    }

    #[test]
    fn locate_nested_fields() {
        let src = "Scene(\n  simulation: (dx: 0.1),\n  bodies: [\n    (name: \"a\", x: 1),\n    (name: \"b\", x: 2),\n  ],\n)";
        assert_eq!(locate(src, "simulation.dx"), (2, 16));
        assert_eq!(locate(src, "bodies[1].x"), (5, 17));
        assert_eq!(locate(src, "bodies[0].name"), (4, 6));
    }

    #[test]
    fn locate_tuple_items() {
        let src = "Scene(\n  colliders: [\n    (name: \"a\", rotation_deg: (0.0, NaN, 0.0)),\n  ],\n  b: [1],\n)";
        // The item inside the tuple, not a later list's.
        assert_eq!(locate(src, "colliders[0].rotation_deg[1]"), (3, 37));
        assert_eq!(locate(src, "colliders[0].rotation_deg[2]"), (3, 42));
    }
}
