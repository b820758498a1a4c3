//! Reading a scene file, and locating an error's field in its text (line and column).

use super::Scene;
use crate::error::{FieldError, SceneError};
use std::path::Path;

impl Scene {
    /// Reads, parses and validates a scene file.
    pub fn load(path: impl AsRef<Path>) -> Result<Scene, SceneError> {
        let path = path.as_ref();
        let src = std::fs::read_to_string(path).map_err(|cause| SceneError::Io {
            file: path.to_path_buf(),
            cause,
        })?;
        Self::parse(&src, path)
    }

    /// Parses and validates scene text; `path` is used in messages.
    pub fn parse(src: &str, path: &Path) -> Result<Scene, SceneError> {
        let mut scene: Scene = ron::Options::default()
            .with_default_extension(ron::extensions::Extensions::IMPLICIT_SOME)
            .from_str(src)
            .map_err(|e| {
                let (line, col) = (e.span.start.line, e.span.start.col);
                let code = e.code.to_string();
                SceneError::Parse {
                    file: path.to_path_buf(),
                    line,
                    col,
                    // ron names the problem but not the field ("Integer is out of bounds").
                    message: match field_before(src, line, col) {
                        Some(f) if !code.contains(&f) => format!("field `{f}`: {code}"),
                        _ => code,
                    },
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
            field: e.field,
            value: e.value,
            expected: e.expected,
        }
    }
}

/// The field whose value starts the text at 1-based `line`, `col` of `src`: the name before
/// the last `:` on that line, when only the start of a plain value (a number, a sign, a word)
/// lies between that `:` and `col`. `None` inside a tuple, list or map, or off a value.
fn field_before(src: &str, line: usize, col: usize) -> Option<String> {
    let text = src.lines().nth(line.checked_sub(1)?)?;
    let prefix: String = text.chars().take(col.saturating_sub(1)).collect();
    let colon = prefix.rfind(':')?;
    let value = &prefix[colon + 1..];
    if value
        .chars()
        .any(|c| matches!(c, ',' | '(' | ')' | '[' | ']' | '{' | '}' | '"'))
    {
        return None;
    }
    let name: String = prefix[..colon]
        .trim_end()
        .chars()
        .rev()
        .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
        .collect::<Vec<_>>()
        .into_iter()
        .rev()
        .collect();
    (!name.is_empty() && !name.starts_with(|c: char| c.is_ascii_digit())).then_some(name)
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
