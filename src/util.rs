//! Small helpers: atomic file writes, peak memory and percentages.

use std::io::Write;
use std::path::{Path, PathBuf};

/// Temporary sibling path used while a file is being written.
pub fn partial_path(path: &Path) -> PathBuf {
    let mut name = path
        .file_name()
        .map(|n| n.to_os_string())
        .unwrap_or_default();
    name.push(".partial");
    path.with_file_name(name)
}

/// Writes `bytes` to `path` atomically: to a temporary sibling first, then renamed, so a reader
/// never sees a half-written file.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let tmp = partial_path(path);
    {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
    }
    std::fs::rename(&tmp, path)
}

/// Checks, before any work starts, that an output file can be written at `path`: its folder
/// exists and is a folder, and `path` itself is not a folder. `flag` names the option that gave
/// the path, so the error says which argument to fix. Without this a missing folder surfaced
/// only when the file was opened, after the whole run, and the Rerun sink repeated its cause
/// three times.
pub fn check_output_file(path: &Path, flag: &str) -> anyhow::Result<()> {
    if path.is_dir() {
        anyhow::bail!(
            "{flag} {}: is a folder; give a file name inside it",
            path.display()
        );
    }
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => return Ok(()),
    };
    if !dir.exists() {
        anyhow::bail!(
            "{flag} {}: the folder {} does not exist; create it first (mkdir -p {})",
            path.display(),
            dir.display(),
            dir.display()
        );
    }
    if !dir.is_dir() {
        anyhow::bail!(
            "{flag} {}: {} is a file, not a folder; choose another path",
            path.display(),
            dir.display()
        );
    }
    Ok(())
}

/// Creates the output folder `dir` (and its parents) given by option `flag`, with an error that
/// says what to do where a file already holds that name.
pub fn create_output_dir(dir: &Path, flag: &str) -> anyhow::Result<()> {
    if dir.exists() && !dir.is_dir() {
        anyhow::bail!(
            "{flag} {}: is a file, not a folder; give a folder for the outputs",
            dir.display()
        );
    }
    std::fs::create_dir_all(dir).map_err(|e| {
        anyhow::anyhow!(
            "{flag} {}: cannot create the output folder: {e}; choose a writable folder",
            dir.display()
        )
    })
}

/// The value in kB of the line `key` of a `/proc` file (`VmHWM:` of `/proc/self/status`,
/// `MemAvailable:` of `/proc/meminfo`), in bytes; `None` where the file or the line is missing.
fn proc_kb(file: &str, key: &str) -> Option<u64> {
    let s = std::fs::read_to_string(file).ok()?;
    let l = s.lines().find(|l| l.starts_with(key))?;
    let kb: u64 = l.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Peak resident set size of this process in bytes (Linux `VmHWM`), or 0 where unknown.
pub fn peak_rss_bytes() -> u64 {
    proc_kb("/proc/self/status", "VmHWM:").unwrap_or(0)
}

/// Memory this process can still get: the kernel's `MemAvailable` (what it can give without
/// swapping), and under an address-space limit (`ulimit -v`, a batch system's cap) no more
/// than the limit less the address space already mapped, since an allocation past the limit
/// aborts the process. `None` where neither is known.
pub fn available_memory_bytes() -> Option<u64> {
    let physical = proc_kb("/proc/meminfo", "MemAvailable:");
    let headroom = address_space_limit()
        .map(|limit| limit.saturating_sub(proc_kb("/proc/self/status", "VmSize:").unwrap_or(0)));
    match (physical, headroom) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    }
}

/// The soft address-space limit of this process in bytes (`Max address space` of
/// `/proc/self/limits`), `None` when unlimited or unknown.
fn address_space_limit() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/limits").ok()?;
    let l = s.lines().find(|l| l.starts_with("Max address space"))?;
    l.split_whitespace().nth(3)?.parse().ok()
}

/// Knuth's MMIX linear congruential generator: the fixed stream the unit and finite-difference
/// tests draw their random cases from (one place, so that every test's cases stay the same
/// bits). Not for the simulation or the studies, which use [`SplitMix64`].
#[derive(Clone, Debug)]
pub struct Lcg(pub u64);

impl Lcg {
    /// The next state, all 64 bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        self.0
    }

    /// Uniform in [0, 1), with 53 bits of the state.
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in [−1, 1).
    pub fn symmetric(&mut self) -> f64 {
        self.uniform() * 2.0 - 1.0
    }
}

/// [`Lcg::uniform`] of the stream whose state is `state`, advancing it (for tests that keep
/// the state as a bare number).
pub fn lcg_uniform(state: &mut u64) -> f64 {
    let mut g = Lcg(*state);
    let x = g.uniform();
    *state = g.0;
    x
}

/// [`Lcg::symmetric`] of the stream whose state is `state`, advancing it.
pub fn lcg_symmetric(state: &mut u64) -> f64 {
    lcg_uniform(state) * 2.0 - 1.0
}

/// A small deterministic generator (SplitMix64, Steele et al. 2014): the lattice jitter and
/// every random draw of `optimize` come from it, so a seed fixes the numbers on any machine and
/// for any thread count.
#[derive(Clone, Debug)]
pub struct SplitMix64(pub u64);

impl SplitMix64 {
    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1), with 53 random bits.
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in [lo, hi).
    pub fn uniform_in(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }

    /// Standard normal (Box–Muller; one draw per call, the second value is discarded so the
    /// stream position depends only on the number of calls).
    pub fn normal(&mut self) -> f64 {
        let u1 = 1.0 - self.uniform(); // (0, 1]
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    /// Uniform index in `0..n` (n > 0).
    pub fn index(&mut self, n: usize) -> usize {
        ((self.uniform() * n as f64) as usize).min(n - 1)
    }
}

/// A fraction as a percentage: two decimals, or two significant digits where that would print a
/// non-zero value as "0.00 %" (the error-vs-time table's transport gradient agrees with finite
/// differences to a few 1e-5, and the stability table's energy rises must show a true 0).
pub fn percent(v: f64) -> String {
    let p = 100.0 * v;
    if p != 0.0 && p.abs() < 0.005 {
        format!("{p:.1e} %")
    } else {
        format!("{p:.2} %")
    }
}

/// FNV-1a, 64 bits: a stable fingerprint of a text (a scene's, a node's, a
/// network's), the same on every machine.
pub fn fnv1a(text: &str) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in text.bytes() {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    format!("{h:016x}")
}

/// A progress bar of `len` units, hidden when `quiet`.
pub fn progress_bar(len: u64, quiet: bool) -> indicatif::ProgressBar {
    if quiet {
        return indicatif::ProgressBar::hidden();
    }
    let pb = indicatif::ProgressBar::new(len);
    pb.set_style(
        indicatif::ProgressStyle::with_template(
            "{elapsed_precise} [{bar:40}] {pos}/{len} {msg} (eta {eta})",
        )
        .expect("static template")
        .progress_chars("=> "),
    );
    pb
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn small_errors_keep_their_digits() {
        assert_eq!(percent(0.0), "0.00 %");
        assert_eq!(percent(2.5e-5), "2.5e-3 %");
        assert_eq!(percent(-4.9e-7), "-4.9e-5 %");
        assert_eq!(percent(5e-5), "0.01 %");
        assert_eq!(percent(0.049), "4.90 %");
    }
}
