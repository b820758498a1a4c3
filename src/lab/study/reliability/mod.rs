//! `powderlab study reliability`: `simulate` on mutated scene files, each in a process of its
//! own under an address-space cap and a timeout, and every outcome classified.
//!
//! Case `i` is `scene::fuzz::case(seed, k)` of the seed scene `i mod n` with `k = i / n`, so a
//! case is reproduced from its seed's name and number alone. Each finished case is appended to
//! a journal (one JSON line), so the study resumes after a kill. The classification is pure
//! ([`classify`]) and unit-tested; the process handling is the small [`run_case`].

mod command;

use crate::scene::fuzz;
use anyhow::{Context, Result};
pub use command::ReliabilityStudy;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// The study's settings.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Config {
    /// Mutated scenes to run.
    pub cases: usize,
    /// Address-space cap per process, in bytes (`ulimit -v`).
    pub cap_bytes: u64,
    /// Wall-clock limit per process.
    pub timeout_s: f64,
    /// Processes side by side.
    pub jobs: usize,
}

/// How one case ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// Refused before the run started, with exit 2.
    Refused,
    /// Accepted and run to its horizon, exit 0.
    Ran,
    /// Accepted, then stopped by an error mid-run (exit 2 after the run began).
    FailedMidRun,
    /// Killed by the timeout.
    Timeout,
    /// A panic (exit 101 or "panicked at").
    Panic,
    /// Ended by a signal it was not sent by the study: an abort (a failed allocation under the
    /// cap), a segmentation fault, or the kernel's OOM killer.
    Killed,
    /// Any other exit status.
    OtherExit,
}

/// One finished case, as journalled.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Record {
    pub seed: String,
    pub k: u64,
    pub outcome: Outcome,
    pub code: Option<i32>,
    pub signal: Option<i32>,
    pub wall_s: f64,
    /// The run's printed work estimate, in seconds at the reference rate, when it printed one.
    pub estimate_s: Option<f64>,
    /// The last line of stderr, cut to 300 characters.
    pub last_line: String,
    /// What breaks the acceptance, if anything (see [`problem`]).
    pub problem: Option<String>,
}

/// A timeout is announced when the printed estimate is at least this fraction of the timeout.
/// The estimate is at the reference rate (3 M particle-substeps/s on two threads); with two
/// cases side by side on two cores each runs at about half of it, and the estimate leaves out
/// the grid's own work, so a run estimated at a quarter of the timeout can reach it.
pub const ANNOUNCED_FRACTION: f64 = 0.25;

/// The words of `text` (runs of letters, digits, `.`, `+`, `-`).
fn words(text: &str) -> impl Iterator<Item = &str> {
    text.split(|c: char| !(c.is_ascii_alphanumeric() || matches!(c, '.' | '+' | '-')))
        .filter(|w| !w.is_empty())
}

/// Whether `text` prints a non-finite number: the words `NaN`, `inf` or `infinity`, with any
/// sign and case.
pub fn prints_non_finite(text: &str) -> bool {
    words(text).any(|w| {
        let w = w.trim_start_matches(['+', '-']).to_ascii_lowercase();
        matches!(w.as_str(), "nan" | "inf" | "infinity")
    })
}

/// The work estimate `simulate` prints (`work: … about 12 s at the reference …`), in seconds.
pub fn estimate_seconds(stderr: &str) -> Option<f64> {
    let line = stderr.lines().find(|l| l.starts_with("work: "))?;
    let rest = &line[line.find(", about ")? + 8..];
    let mut it = rest.split_whitespace();
    let x: f64 = it.next()?.parse().ok()?;
    let unit = match it.next()? {
        "s" => 1.0,
        "min" => 60.0,
        "h" => 3600.0,
        "days" => 86400.0,
        _ => return None,
    };
    Some(x * unit)
}

/// Whether the run began: `simulate` prints `FILE: N particles, T steps × S substeps, …;
/// systems: …` just before its first step.
fn started(stderr: &str) -> bool {
    stderr
        .lines()
        .any(|l| l.contains(" particles, ") && l.contains(" substeps, ") && l.contains("systems:"))
}

/// What is wrong with a refusal's stderr, if anything: it must hold exactly one error line,
/// the last, that names the file and a field, with a line and column wherever the error comes
/// from the text (the work limit is a refusal of the whole scene after it loaded, and names the
/// field that drives it).
pub fn bad_refusal(stderr: &str, file: &str) -> Option<String> {
    let errors: Vec<&str> = stderr
        .lines()
        .filter(|l| l.starts_with("error: "))
        .collect();
    if errors.len() != 1 {
        return Some(format!("{} error lines", errors.len()));
    }
    let e = errors[0];
    if stderr.lines().last() != Some(e) {
        return Some("the error is not the last line".into());
    }
    if e.chars().count() > 1000 {
        return Some(format!("{} characters", e.chars().count()));
    }
    let Some(rest) = e.strip_prefix("error: ").and_then(|r| r.strip_prefix(file)) else {
        return Some("does not begin with the file".into());
    };
    if !e.contains('`') {
        return Some("names no field".into());
    }
    let positioned = rest
        .strip_prefix(':')
        .and_then(|r| r.split_once(':'))
        .and_then(|(line, r)| Some((line, r.split_once(':')?.0)))
        .is_some_and(|(l, c)| l.parse::<usize>().is_ok() && c.parse::<usize>().is_ok());
    if !positioned && !e.contains("pass --force") {
        return Some("no line and column".into());
    }
    None
}

/// Classifies a finished process: its exit code, or the signal that ended it (and whether the
/// study sent it), and its stderr.
pub fn classify(code: Option<i32>, signal: Option<i32>, timed_out: bool, stderr: &str) -> Outcome {
    if timed_out {
        Outcome::Timeout
    } else if code == Some(101) || stderr.contains("panicked at") {
        Outcome::Panic
    } else if signal.is_some() {
        Outcome::Killed
    } else if code == Some(0) {
        Outcome::Ran
    } else if code == Some(2) {
        if started(stderr) {
            Outcome::FailedMidRun
        } else {
            Outcome::Refused
        }
    } else {
        Outcome::OtherExit
    }
}

/// What breaks the acceptance: a panic, a kill, an accepted run that prints a non-finite
/// number or fails mid-run, a refusal that is not one good line, or a timeout the estimate did
/// not announce.
pub fn problem(
    outcome: Outcome,
    stderr: &str,
    file: &str,
    estimate_s: Option<f64>,
    timeout_s: f64,
) -> Option<String> {
    match outcome {
        Outcome::Refused => bad_refusal(stderr, file).map(|w| format!("refusal: {w}")),
        Outcome::Ran if prints_non_finite(stderr) => Some("accepted; prints NaN or inf".into()),
        Outcome::Ran => None,
        Outcome::FailedMidRun => Some("accepted, then failed mid-run".into()),
        Outcome::Timeout => match estimate_s {
            Some(e) if e >= ANNOUNCED_FRACTION * timeout_s => None,
            Some(e) => Some(format!("timeout; the estimate said {e:.0} s")),
            None => Some("timeout before any estimate".into()),
        },
        Outcome::Panic => Some("panic".into()),
        Outcome::Killed => Some("killed by a signal".into()),
        Outcome::OtherExit => Some("unexpected exit status".into()),
    }
}

/// Runs `exe simulate FILE` under the cap and the timeout, and classifies it. The mutated
/// scene is written to `work/` and removed afterwards; the failing ones are kept in
/// `failing/` for reproduction.
pub fn run_case(
    exe: &Path,
    dir: &Path,
    seed_name: &str,
    seed_text: &[u8],
    k: u64,
    cfg: &Config,
) -> Result<Record> {
    use std::os::unix::process::ExitStatusExt;
    let work = dir.join("work");
    std::fs::create_dir_all(&work)?;
    let stem = format!("{}-{k}", seed_name.trim_end_matches(".ron"));
    let file = work.join(format!("{stem}.ron"));
    let err_path = work.join(format!("{stem}.stderr"));
    std::fs::write(&file, fuzz::case(seed_text, k))?;
    let err_file = std::fs::File::create(&err_path)?;
    let start = Instant::now();
    let mut child = Command::new("sh")
        .arg("-c")
        .arg(format!(
            "ulimit -v {} && exec \"$0\" \"$@\"",
            cfg.cap_bytes / 1024
        ))
        .arg(exe)
        .arg("simulate")
        .arg(&file)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(err_file)
        .spawn()
        .context("cannot start sh")?;
    let limit = Duration::from_secs_f64(cfg.timeout_s);
    let mut timed_out = false;
    let status = loop {
        if let Some(s) = child.try_wait()? {
            break s;
        }
        if start.elapsed() > limit {
            timed_out = true;
            child.kill().ok();
            break child.wait()?;
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    let wall_s = start.elapsed().as_secs_f64();
    let stderr = String::from_utf8_lossy(&std::fs::read(&err_path)?).into_owned();
    let (code, signal) = (status.code(), status.signal());
    let outcome = classify(code, signal, timed_out, &stderr);
    let file_str = file.display().to_string();
    let estimate_s = estimate_seconds(&stderr);
    let problem = problem(outcome, &stderr, &file_str, estimate_s, cfg.timeout_s);
    let last_line: String = stderr
        .lines()
        .last()
        .unwrap_or("")
        .replace(&file_str, "FILE")
        .chars()
        .take(300)
        .collect();
    if problem.is_some() {
        let keep = dir.join("failing");
        std::fs::create_dir_all(&keep)?;
        std::fs::rename(&file, keep.join(format!("{stem}.ron")))?;
        std::fs::rename(&err_path, keep.join(format!("{stem}.stderr")))?;
    } else {
        std::fs::remove_file(&file).ok();
        std::fs::remove_file(&err_path).ok();
    }
    Ok(Record {
        seed: seed_name.to_string(),
        k,
        outcome,
        code,
        signal,
        wall_s,
        estimate_s,
        last_line,
        problem,
    })
}

/// The journal's records, by (seed, k). A torn last line (a kill mid-write) is skipped.
pub fn read_journal(path: &Path) -> Result<BTreeMap<(String, u64), Record>> {
    Ok(crate::lab::journal::read::<Record>(path)?
        .into_iter()
        .map(|r| ((r.seed.clone(), r.k), r))
        .collect())
}

/// Runs the cases the journal lacks, `cfg.jobs` at a time, appending each as it ends, and
/// returns every record of the first `cfg.cases` cases.
pub fn run(
    exe: &Path,
    root: &Path,
    dir: &Path,
    cfg: &Config,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Vec<Record>> {
    std::fs::create_dir_all(dir)?;
    let journal = dir.join("cases.jsonl");
    // A torn last line (killed mid-write) is cut off.
    let (writer, kept) = crate::lab::journal::Journal::<Record>::open(&journal)?;
    let done: BTreeMap<(String, u64), Record> = kept
        .into_iter()
        .map(|r| ((r.seed.clone(), r.k), r))
        .collect();
    let seeds = fuzz::seeds(root)
        .with_context(|| format!("reading the seed scenes under {}", root.display()))?;
    let texts: Vec<(String, Vec<u8>)> = seeds
        .iter()
        .map(|p| {
            let name = p
                .file_name()
                .unwrap_or_default()
                .to_string_lossy()
                .into_owned();
            Ok((name, std::fs::read(p)?))
        })
        .collect::<Result<_>>()?;
    let n = texts.len();
    let todo: Vec<(usize, u64)> = (0..cfg.cases)
        .map(|i| (i % n, (i / n) as u64))
        .filter(|&(s, k)| !done.contains_key(&(texts[s].0.clone(), k)))
        .collect();
    let next = std::sync::atomic::AtomicUsize::new(0);
    let finished = std::sync::atomic::AtomicUsize::new(cfg.cases - todo.len());
    progress(
        finished.load(std::sync::atomic::Ordering::Relaxed),
        cfg.cases,
    );
    std::thread::scope(|s| -> Result<()> {
        let workers: Vec<_> = (0..cfg.jobs.max(1))
            .map(|_| {
                s.spawn(|| -> Result<()> {
                    loop {
                        let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        let Some(&(seed, k)) = todo.get(i) else {
                            return Ok(());
                        };
                        let (name, text) = &texts[seed];
                        let r = run_case(exe, dir, name, text, k, cfg)?;
                        writer.append(&r)?;
                        let f = finished.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
                        progress(f, cfg.cases);
                    }
                })
            })
            .collect();
        for w in workers {
            w.join().expect("worker thread")?;
        }
        Ok(())
    })?;
    let all = read_journal(&journal)?;
    Ok((0..cfg.cases)
        .filter_map(|i| all.get(&(texts[i % n].0.clone(), (i / n) as u64)).cloned())
        .collect())
}

/// The results page.
pub fn report(records: &[Record], cfg: &Config, command: &str, machine: &str) -> String {
    use std::fmt::Write as _;
    let mut md = String::new();
    let count = |o: Outcome| records.iter().filter(|r| r.outcome == o).count();
    let problems: Vec<&Record> = records.iter().filter(|r| r.problem.is_some()).collect();
    let _ = writeln!(md, "# Reliability: `simulate` on mutated scene files\n");
    let _ = writeln!(md, "Regenerate: `{command}`  \nMachine: {machine}.\n");
    let _ = writeln!(
        md,
        "Each case is one of the shipped or test scenes with one to three mutations from `scene::fuzz` (numbers replaced by extremes or scaled by 10^±12, spans deleted, duplicated or truncated, stray punctuation, invalid UTF-8, identifiers up to 20,000 characters), run as `powderlab simulate FILE` in a process of its own under an address-space cap of {:.0} GB (`ulimit -v`) and a {:.0} s timeout, {} side by side. Case `k` of a seed is `fuzz::case(seed, k)`, so any case is reproduced from its name. A timeout counts as announced when the run's printed work estimate is at least {:.0} % of the timeout (the estimate is at the reference rate of two threads; two cases side by side run at about half of it).\n",
        cfg.cap_bytes as f64 / (1u64 << 30) as f64,
        cfg.timeout_s,
        cfg.jobs,
        100.0 * ANNOUNCED_FRACTION
    );
    let total = records.len();
    let _ = writeln!(md, "## Outcomes of {total} mutated scenes\n");
    let _ = writeln!(md, "| outcome | cases |\n|---|---|");
    for (o, what) in [
        (Outcome::Refused, "refused before running (exit 2)"),
        (Outcome::Ran, "accepted and run to the end (exit 0)"),
        (Outcome::Timeout, "stopped by the timeout"),
        (Outcome::FailedMidRun, "accepted, then failed mid-run"),
        (Outcome::Panic, "panic"),
        (
            Outcome::Killed,
            "abort or kill (a signal the study did not send)",
        ),
        (Outcome::OtherExit, "another exit status"),
    ] {
        let _ = writeln!(md, "| {what} | {} |", count(o));
    }
    let nonfinite = records
        .iter()
        .filter(|r| r.outcome == Outcome::Ran && r.problem.is_some())
        .count();
    let bad_refusals = records
        .iter()
        .filter(|r| r.outcome == Outcome::Refused && r.problem.is_some())
        .count();
    let unannounced = records
        .iter()
        .filter(|r| r.outcome == Outcome::Timeout && r.problem.is_some())
        .count();
    let _ = writeln!(md, "\n## Against the acceptance\n");
    let _ = writeln!(md, "| check | count |\n|---|---|");
    let _ = writeln!(md, "| panics | {} |", count(Outcome::Panic));
    let _ = writeln!(
        md,
        "| aborts or kills by the cap | {} |",
        count(Outcome::Killed)
    );
    let _ = writeln!(
        md,
        "| accepted scenes that print NaN or inf, or fail mid-run | {} |",
        nonfinite + count(Outcome::FailedMidRun)
    );
    let _ = writeln!(
        md,
        "| refusals that are not one line with the file, a field, and a line and column | {bad_refusals} |"
    );
    let _ = writeln!(
        md,
        "| timeouts the printed estimate did not announce | {unannounced} |"
    );
    let timeouts: Vec<f64> = records
        .iter()
        .filter(|r| r.outcome == Outcome::Timeout)
        .filter_map(|r| r.estimate_s)
        .collect();
    if !timeouts.is_empty() {
        let lo = timeouts.iter().cloned().fold(f64::INFINITY, f64::min);
        let _ = writeln!(
            md,
            "\nThe {} timeouts' printed estimates run from {lo:.0} s to {:.3e} s.",
            timeouts.len(),
            timeouts.iter().cloned().fold(0.0, f64::max)
        );
    }
    let positioned = records
        .iter()
        .filter(|r| {
            r.outcome == Outcome::Refused
                && r.last_line
                    .strip_prefix("error: FILE:")
                    .is_some_and(|t| t.starts_with(|c: char| c.is_ascii_digit()))
        })
        .count();
    let _ = writeln!(
        md,
        "\nOf the refusals, {positioned} carry `FILE:LINE:COLUMN` and a field; {} (the rest) are the work limit's refusal of a loaded scene whose work no one field of the file drives (the horizon a skill's controls take, the particle count), and name the file and what to change.",
        count(Outcome::Refused) - positioned
    );
    let _ = writeln!(md, "\n## By seed scene\n");
    let _ = writeln!(
        md,
        "| seed | cases | refused | ran | timeout | problems | slowest run (s) |\n|---|---|---|---|---|---|---|"
    );
    let mut by_seed: BTreeMap<&str, Vec<&Record>> = BTreeMap::new();
    for r in records {
        by_seed.entry(&r.seed).or_default().push(r);
    }
    for (seed, rs) in &by_seed {
        let c = |o: Outcome| rs.iter().filter(|r| r.outcome == o).count();
        let slowest = rs
            .iter()
            .filter(|r| r.outcome == Outcome::Ran)
            .map(|r| r.wall_s)
            .fold(0.0, f64::max);
        let _ = writeln!(
            md,
            "| {seed} | {} | {} | {} | {} | {} | {slowest:.1} |",
            rs.len(),
            c(Outcome::Refused),
            c(Outcome::Ran),
            c(Outcome::Timeout),
            rs.iter().filter(|r| r.problem.is_some()).count()
        );
    }
    let _ = writeln!(
        md,
        "\n## Longer and deeper runs\n\nThe CI test `tests/scene_fuzz.rs` puts 2,500 of these mutations through parse, validate and prepare (no simulation) in about a second, with an allocation counter. For long runs the loader has a coverage-guided AFL++ target in `fuzz/`, which holds the same invariants (no panic, a refusal of one line naming the file):\n\n```sh\ncargo install cargo-afl\ncd fuzz && cargo afl build --release\nAFL_SKIP_CPUFREQ=1 cargo afl fuzz -i ../scenes -o out target/release/scene\n```\n\nAFL keeps any input that breaks an invariant under `fuzz/out/default/crashes/`."
    );
    if !problems.is_empty() {
        let _ = writeln!(md, "\n## Cases that break the acceptance\n");
        let _ = writeln!(
            md,
            "Kept with their stderr under `study/reliability/failing/`; the first 30:\n"
        );
        let _ = writeln!(md, "| case | problem | last line |\n|---|---|---|");
        for r in problems.iter().take(30) {
            let _ = writeln!(
                md,
                "| {}#{} | {} | `{}` |",
                r.seed,
                r.k,
                r.problem.as_deref().unwrap_or(""),
                r.last_line.replace('|', "\\|").replace('`', "'")
            );
        }
    }
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn non_finite_words_are_found_and_other_words_are_not() {
        assert!(prints_non_finite("energy: NaN J -> NaN J"));
        assert!(prints_non_finite("stable substep inf s"));
        assert!(prints_non_finite("x = -inf"));
        assert!(!prints_non_finite(
            "information: infinite care, unlimited, Nancy"
        ));
        assert!(!prints_non_finite("1.5e-3 J -> 2e4 J"));
    }

    #[test]
    fn the_printed_estimate_is_read_in_its_unit() {
        let e = "stability: …\nwork: 10 particles × 2 substeps × 3 steps = 6.00e1 particle-substeps, about 12 min at the reference machine's 3 M particle-substeps/s\n";
        assert_eq!(estimate_seconds(e), Some(720.0));
        assert_eq!(estimate_seconds("no estimate"), None);
    }

    #[test]
    fn a_refusal_is_one_last_line_with_file_field_and_position() {
        let f = "study/x.ron";
        let good =
            "error: study/x.ron:3:14: field `simulation.dx` = 0 is out of range: expected 1e-6..10";
        assert_eq!(bad_refusal(good, f), None);
        assert!(bad_refusal("error: study/x.ron: something broke", f).is_some());
        assert!(bad_refusal("error: study/x.ron:3:14: no field", f).is_some());
        assert!(bad_refusal(&format!("{good}\n{good}"), f).is_some());
        assert!(bad_refusal(&format!("{good}\nafter"), f).is_some());
        let work = "error: study/x.ron: 1 particles × …, over the limit of 1e10: `simulation.substeps` = 5000000 asks for them; pass --force to run it anyway";
        assert_eq!(bad_refusal(work, f), None);
    }

    #[test]
    fn outcomes_follow_the_exit_and_whether_the_run_began() {
        let begun = "x.ron: 10 particles, 5 steps × 2 substeps, 1 threads; systems: a → b\nerror: non-finite";
        assert_eq!(classify(Some(2), None, false, begun), Outcome::FailedMidRun);
        assert_eq!(classify(Some(2), None, false, "error: x"), Outcome::Refused);
        assert_eq!(classify(Some(0), None, false, ""), Outcome::Ran);
        assert_eq!(classify(None, Some(6), false, ""), Outcome::Killed);
        assert_eq!(classify(None, Some(9), true, ""), Outcome::Timeout);
        assert_eq!(
            classify(Some(101), None, false, "thread 'main' panicked at"),
            Outcome::Panic
        );
        assert!(problem(Outcome::Timeout, "", "f", Some(4.0), 20.0).is_some());
        assert_eq!(problem(Outcome::Timeout, "", "f", Some(30.0), 20.0), None);
    }
}
