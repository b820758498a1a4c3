//! A deterministic mutation fuzzer for scene files: the CI test (`tests/scene_fuzz.rs`) and
//! long runs draw mutated scenes from it.
//!
//! Case `k` of a seed text is the text with one to three mutations drawn by `SplitMix64(k)`, so
//! any failing case is reproduced from its number alone. The mutations are those that found
//! the loader's faults: numbers replaced by extremes (0, ±1e308, 1e-320, NaN, 2³², …) or
//! scaled by a power of ten, spans deleted, duplicated or truncated, stray brackets and
//! punctuation, invalid UTF-8 bytes, and a very long identifier.

use crate::util::SplitMix64;

/// Values a number is replaced by: zero and signs, the f64 and u32/u64 limits, subnormals,
/// the non-finite words, and legal but extreme values.
pub const EXTREMES: &[&str] = &[
    "0",
    "-0.0",
    "-1",
    "1",
    "1e308",
    "-1e308",
    "1e-300",
    "1e-320",
    "NaN",
    "inf",
    "-inf",
    "4294967296",
    "18446744073709551616",
    "1000000",
    "0.4999999",
    "1e40",
    "-1e40",
    "1e9",
    "1e300",
    "3",
];

/// Byte spans of the numbers in `text` (a digit, optionally after `-`/`.`, with the rest of
/// the literal: digits, `.`, `e`, `E`, `+`, `-`, `_`).
pub fn numbers(text: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < text.len() {
        let starts = text[i].is_ascii_digit()
            && (i == 0 || !(text[i - 1].is_ascii_alphanumeric() || text[i - 1] == b'_'));
        if !starts {
            i += 1;
            continue;
        }
        let mut a = i;
        while a > 0 && matches!(text[a - 1], b'-' | b'.') {
            a -= 1;
        }
        let mut b = i;
        while b < text.len()
            && (text[b].is_ascii_digit() || matches!(text[b], b'.' | b'e' | b'E' | b'_'))
            || (b > 0
                && b < text.len()
                && matches!(text[b], b'+' | b'-')
                && matches!(text[b - 1], b'e' | b'E'))
        {
            b += 1;
        }
        out.push((a, b));
        i = b.max(i + 1);
    }
    out
}

fn pick(rng: &mut SplitMix64, n: usize) -> usize {
    (rng.next_u64() % n.max(1) as u64) as usize
}

/// One mutation of `text`, drawn from `rng`.
pub fn mutate_once(text: &mut Vec<u8>, rng: &mut SplitMix64) {
    let len = text.len();
    match pick(rng, 10) {
        // Numbers: the most productive mutations, so four of the ten.
        0..=2 => {
            let nums = numbers(text);
            if nums.is_empty() {
                return;
            }
            let (a, b) = nums[pick(rng, nums.len())];
            let v = EXTREMES[pick(rng, EXTREMES.len())].as_bytes();
            text.splice(a..b, v.iter().copied());
        }
        3 => {
            let nums = numbers(text);
            if nums.is_empty() {
                return;
            }
            let (a, b) = nums[pick(rng, nums.len())];
            let old = String::from_utf8_lossy(&text[a..b]).replace('_', "");
            let Ok(x) = old.parse::<f64>() else {
                return;
            };
            let scaled = x * 10f64.powi(pick(rng, 25) as i32 - 12);
            let v = if old.contains(['.', 'e', 'E']) {
                format!("{scaled:e}")
            } else {
                format!("{}", scaled.round() as i64)
            };
            text.splice(a..b, v.bytes());
        }
        4 => {
            // Delete a span.
            let a = pick(rng, len);
            let b = (a + 1 + pick(rng, 60)).min(len);
            text.drain(a..b);
        }
        5 => {
            // Duplicate a span in place.
            let a = pick(rng, len);
            let b = (a + 1 + pick(rng, 60)).min(len);
            let span: Vec<u8> = text[a..b].to_vec();
            text.splice(b..b, span);
        }
        6 => {
            // Truncate.
            text.truncate(pick(rng, len));
        }
        7 => {
            // Stray punctuation.
            let p = b"()[]{},:\"'#/";
            let at = pick(rng, len + 1);
            text.insert(at, p[pick(rng, p.len())]);
        }
        8 => {
            // Invalid UTF-8: a lone continuation byte, an overlong lead, or a truncated sequence.
            let bad: &[&[u8]] = &[&[0xFF], &[0x80], &[0xC3], &[0xE2, 0x82]];
            let at = pick(rng, len + 1);
            let b = bad[pick(rng, bad.len())];
            text.splice(at..at, b.iter().copied());
        }
        _ => {
            // A long identifier where a field name may stand.
            let at = pick(rng, len + 1);
            let name = "a".repeat(1 + pick(rng, 20_000));
            text.splice(at..at, format!("{name}: 1, ").into_bytes());
        }
    }
}

/// The seed scenes under `root`: the shipped ones (`scenes/`) and the tests' (`tests/scenes/`),
/// sorted by path. The CI fuzz test and `study reliability` mutate the same seeds.
pub fn seeds(root: &std::path::Path) -> std::io::Result<Vec<std::path::PathBuf>> {
    let mut out = Vec::new();
    for dir in ["scenes", "tests/scenes"] {
        for e in std::fs::read_dir(root.join(dir))? {
            let p = e?.path();
            if p.extension().is_some_and(|x| x == "ron") {
                out.push(p);
            }
        }
    }
    out.sort();
    Ok(out)
}

/// Case `k` of `seed`: one to three mutations drawn from `SplitMix64(k)`.
pub fn case(seed: &[u8], k: u64) -> Vec<u8> {
    let mut rng = SplitMix64(0xF022_0000_0000 ^ k);
    let mut text = seed.to_vec();
    for _ in 0..1 + pick(&mut rng, 3) {
        mutate_once(&mut text, &mut rng);
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_are_found_whole_with_their_sign_and_exponent() {
        let t = b"dx: 0.005, cells: (24, 1e-3, -2.5E+4), name: \"cup2\", x_1: 7";
        let found: Vec<&str> = numbers(t)
            .iter()
            .map(|&(a, b)| std::str::from_utf8(&t[a..b]).unwrap())
            .collect();
        assert_eq!(found, ["0.005", "24", "1e-3", "-2.5E+4", "7"]);
    }

    #[test]
    fn a_case_is_reproduced_from_its_number() {
        let seed = b"Scene(simulation: (dx: 0.005, cells: (24, 24, 24)))";
        assert_eq!(case(seed, 17), case(seed, 17));
        assert!((0..50).any(|k| case(seed, k) != case(seed, 18)));
    }
}
