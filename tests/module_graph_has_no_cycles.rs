//! No two modules of the library import each other, directly or around a loop: the scene layer
//! stays below the simulation, the material registry above the stages, and so on
//! (`docs/design.md` §6, "Layers").
//!
//! A module is a file under `src/` (`mod.rs` and `lib.rs` stand for their folder). A module
//! depends on another when its code (comments and `#[cfg(test)]` modules left out) names a path
//! `crate::a::b` or `super::…` that resolves to it. A module and its own descendants are one
//! unit here: Rust declares children in their parent, and children use their parent's items.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// Module path (`scene::prepare`) of every library file, with its source.
fn modules() -> BTreeMap<String, String> {
    fn walk(dir: &Path, root: &Path, out: &mut BTreeMap<String, String>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(&p, root, out);
                continue;
            }
            if p.extension().is_none_or(|x| x != "rs") {
                continue;
            }
            let rel = p.strip_prefix(root).unwrap().with_extension("");
            let mut parts: Vec<String> = rel
                .components()
                .map(|c| c.as_os_str().to_string_lossy().into_owned())
                .collect();
            // The binary and its commands are not the library.
            if parts[0] == "main" || parts[0] == "cli" {
                continue;
            }
            if matches!(parts.last().map(String::as_str), Some("mod" | "lib")) {
                parts.pop();
            }
            out.insert(parts.join("::"), std::fs::read_to_string(&p).unwrap());
        }
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut out = BTreeMap::new();
    walk(&root, &root, &mut out);
    out
}

/// The source without comments and without its `#[cfg(test)] mod tests` block.
fn code(src: &str) -> String {
    let src = match src.find("#[cfg(test)]\nmod tests") {
        Some(i) => &src[..i],
        None => src,
    };
    src.lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n")
}

/// Every `crate::…` or `super::…` path in `code`, as written (segments joined by `::`); a
/// group `crate::a::{b, c::d}` gives `crate::a::b` and `crate::a::c::d`.
fn paths(code: &str) -> Vec<String> {
    let mut out = Vec::new();
    let bytes = code.as_bytes();
    for start in ["crate::", "super::"] {
        let mut from = 0;
        while let Some(i) = code[from..].find(start) {
            let at = from + i;
            from = at + start.len();
            if at > 0 && (bytes[at - 1].is_ascii_alphanumeric() || bytes[at - 1] == b'_') {
                continue;
            }
            let end = path_end(code, at);
            let prefix = code[at..end].trim_end_matches(':');
            if code[end..].starts_with('{') {
                expand(prefix, &code[end + 1..], &mut out);
            } else {
                out.push(prefix.to_string());
            }
        }
    }
    out
}

/// Where the path starting at `at` ends (at the first character that is not part of it).
fn path_end(code: &str, at: usize) -> usize {
    let bytes = code.as_bytes();
    let mut end = at;
    while end < code.len() && (bytes[end].is_ascii_alphanumeric() || b"_:".contains(&bytes[end])) {
        end += 1;
    }
    end
}

/// The items of the group whose text starts right after its `{`, each appended to `prefix`.
fn expand(prefix: &str, group: &str, out: &mut Vec<String>) {
    let mut depth = 0;
    let mut item_start = 0;
    for (i, c) in group.char_indices() {
        match c {
            '{' => depth += 1,
            '}' if depth > 0 => depth -= 1,
            ',' if depth > 0 => {}
            '}' | ',' => {
                let item = group[item_start..i].trim();
                let end = path_end(item, 0);
                let head = item[..end].trim_end_matches(':');
                let full = if head.is_empty() || head == "self" {
                    prefix.to_string()
                } else {
                    format!("{prefix}::{head}")
                };
                if item[end..].starts_with('{') {
                    expand(&full, &item[end + 1..], out);
                } else {
                    out.push(full);
                }
                if c == '}' {
                    return;
                }
                item_start = i + 1;
            }
            _ => {}
        }
    }
}

/// The module `path`, written in module `me` (a folder module when `dir`), refers to: the
/// longest prefix that is a module.
fn resolve(path: &str, me: &str, dir: bool, mods: &BTreeMap<String, String>) -> Option<String> {
    let mut segs: Vec<&str> = path.split("::").collect();
    let mut base: Vec<&str> = if me.is_empty() {
        Vec::new()
    } else {
        me.split("::").collect()
    };
    if !dir {
        // A file module's `super` is its parent; its own items are `self`.
        base.pop();
        base.push("\0self");
    }
    if segs[0] == "crate" {
        base.clear();
        segs.remove(0);
    } else {
        while segs.first() == Some(&"super") {
            segs.remove(0);
            base.pop();
        }
        base.retain(|s| *s != "\0self");
    }
    let full: Vec<&str> = base.into_iter().chain(segs).collect();
    (1..=full.len())
        .rev()
        .map(|k| full[..k].join("::"))
        .find(|m| mods.contains_key(m))
}

fn related(a: &str, b: &str) -> bool {
    a.is_empty()
        || b.is_empty()
        || a.starts_with(&format!("{b}::"))
        || b.starts_with(&format!("{a}::"))
}

/// Which modules each module imports (a module and its descendants count as one).
fn edges(mods: &BTreeMap<String, String>) -> BTreeMap<String, BTreeSet<String>> {
    let mut edges: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for (me, src) in mods {
        let dir = mods.keys().any(|m| m.starts_with(&format!("{me}::"))) || me.is_empty();
        for p in paths(&code(src)) {
            if let Some(to) = resolve(&p, me, dir, mods) {
                // A module naming itself (a `$crate::` path in its own macro) is no import.
                if !related(me, &to) && *me != to {
                    edges.entry(me.clone()).or_default().insert(to);
                }
            }
        }
    }
    edges
}

/// The simulator and its adjoint stand alone: no module outside `lab` (the crate root, which
/// only declares it, aside) names anything inside it, so the lab can be left out of a build
/// (`--no-default-features`) and read apart.
#[test]
fn the_simulator_imports_nothing_of_the_lab() {
    let mods = modules();
    let lab: Vec<&String> = mods
        .keys()
        .filter(|m| related(m, "lab") && !m.is_empty())
        .collect();
    assert!(
        lab.len() > 50 && mods.contains_key("lab::optim") && mods.contains_key("lab::study"),
        "the lab's modules were not found under src/lab: {lab:?}"
    );
    let mut offenders = Vec::new();
    for (me, to) in edges(&mods) {
        if me.is_empty() || related(&me, "lab") {
            continue;
        }
        for t in to.iter().filter(|t| !t.is_empty() && related(t, "lab")) {
            offenders.push(format!("{me} → {t}"));
        }
    }
    assert!(
        offenders.is_empty(),
        "core modules import the lab: {offenders:?}"
    );
}

#[test]
fn no_module_imports_one_that_imports_it_back() {
    let mods = modules();
    assert!(
        mods.contains_key("scene::prepare") && mods.contains_key("sim"),
        "{:?}",
        mods.keys()
    );
    let edges = edges(&mods);
    // Depth-first search for a back edge; the cycle is reported as the path around it.
    fn visit(
        m: &str,
        edges: &BTreeMap<String, BTreeSet<String>>,
        state: &mut BTreeMap<String, u8>,
        stack: &mut Vec<String>,
    ) -> Option<Vec<String>> {
        state.insert(m.to_string(), 1);
        stack.push(m.to_string());
        for n in edges.get(m).into_iter().flatten() {
            match state.get(n.as_str()).copied().unwrap_or(0) {
                1 => {
                    let i = stack.iter().position(|s| s == n).unwrap();
                    let mut cycle = stack[i..].to_vec();
                    cycle.push(n.clone());
                    return Some(cycle);
                }
                0 => {
                    if let Some(c) = visit(n, edges, state, stack) {
                        return Some(c);
                    }
                }
                _ => {}
            }
        }
        stack.pop();
        state.insert(m.to_string(), 2);
        None
    }
    let mut state = BTreeMap::new();
    for m in mods.keys() {
        if state.get(m.as_str()).copied().unwrap_or(0) == 0 {
            if let Some(c) = visit(m, &edges, &mut state, &mut Vec::new()) {
                panic!("import cycle: {}", c.join(" → "));
            }
        }
    }
    // The layering the design states.
    for below in [
        "scene",
        "scene::types",
        "scene::parse",
        "scene::validate",
        "scene::prepare",
    ] {
        for above in ["sim", "sim::build", "adjoint", "adjoint::tape", "lab"] {
            assert!(
                !edges
                    .get(below)
                    .is_some_and(|e| e.iter().any(|t| related(t, above) && !t.is_empty())),
                "{below} imports {above}"
            );
        }
    }
}
