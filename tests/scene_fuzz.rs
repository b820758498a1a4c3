//! Scene files under a deterministic mutation fuzzer (`powderlab::scene::fuzz`): every shipped
//! scene, mutated [`CASES_PER_SCENE`] times, is parsed, validated and prepared. No case may
//! panic, allocate past the memory the loader was given, be accepted with a non-finite derived
//! number, or be refused with anything but one bounded line that names the file, a position
//! and a field.
//!
//! This binary holds one test only: its allocator counts the bytes of the whole process.

use powderlab::error::SceneError;
use powderlab::scene::{fuzz, Scene};
use std::alloc::{GlobalAlloc, Layout, System};
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Mutated cases per seed scene (10 seeds: 2,500 cases, a few seconds in release).
const CASES_PER_SCENE: u64 = 250;
/// The memory the loader may take per case: every refusal for size must come before the
/// allocation. The shipped scenes need under 20 MB.
const LOADER_LIMIT: u64 = 256 << 20;
/// Allowance over the limit for what is not the scene's data: the text and its copies, the
/// parser's tree, a 20,000-character identifier.
const SLACK: usize = 64 << 20;
/// Longest refusal, in characters after the file name: a value is cut at 80 characters.
const MAX_MESSAGE: usize = 600;

struct Counting;
static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        let p = unsafe { System.alloc(l) };
        if !p.is_null() {
            let now = LIVE.fetch_add(l.size(), Ordering::Relaxed) + l.size();
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        p
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) };
        LIVE.fetch_sub(l.size(), Ordering::Relaxed);
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, new: usize) -> *mut u8 {
        let q = unsafe { System.realloc(p, l, new) };
        if !q.is_null() {
            if new >= l.size() {
                let now = LIVE.fetch_add(new - l.size(), Ordering::Relaxed) + new - l.size();
                PEAK.fetch_max(now, Ordering::Relaxed);
            } else {
                LIVE.fetch_sub(l.size() - new, Ordering::Relaxed);
            }
        }
        q
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

fn seeds() -> Vec<std::path::PathBuf> {
    fuzz::seeds(Path::new(env!("CARGO_MANIFEST_DIR"))).unwrap()
}

/// What is wrong with a refusal's message, if anything.
fn bad_message(e: &SceneError, file: &str) -> Option<String> {
    let m = e.to_string();
    let rest = m.strip_prefix(file)?;
    if m.contains('\n') {
        return Some("more than one line".into());
    }
    if rest.chars().count() > MAX_MESSAGE {
        return Some(format!("{} characters", rest.chars().count()));
    }
    match e {
        SceneError::Io { .. } => Some("an I/O error for text in memory".into()),
        SceneError::Parse { line, col, .. } | SceneError::Invalid { line, col, .. }
            if *line == 0 || *col == 0 =>
        {
            Some("no position".into())
        }
        _ if !m.contains("field `") => Some("no field named".into()),
        _ => None,
    }
}

#[test]
fn mutated_scenes_are_refused_in_one_line_or_accepted_finite_and_never_panic() {
    let seeds = seeds();
    assert!(seeds.len() >= 10, "{seeds:?}");
    let (mut accepted, mut refused) = (0, 0);
    let mut failures: Vec<String> = Vec::new();
    for seed_path in &seeds {
        let seed = std::fs::read(seed_path).unwrap();
        let name = seed_path.file_name().unwrap().to_string_lossy().to_string();
        for k in 0..CASES_PER_SCENE {
            let text = fuzz::case(&seed, k);
            let file = format!("fuzz/{name}#{k}");
            let base = LIVE.load(Ordering::Relaxed);
            PEAK.store(base, Ordering::Relaxed);
            let outcome = std::panic::catch_unwind(|| {
                Scene::parse_bytes(&text, Path::new(&file))
                    .and_then(|s| s.prepare_within(Some(LOADER_LIMIT)).map(|p| (s, p)))
            });
            let peak = PEAK.load(Ordering::Relaxed).saturating_sub(base);
            if peak > LOADER_LIMIT as usize + SLACK {
                failures.push(format!("{file}: allocated {} MB", peak >> 20));
            }
            match outcome {
                Err(_) => failures.push(format!("{file}: panicked")),
                Ok(Err(e)) => {
                    refused += 1;
                    if let Some(why) = bad_message(&e, &file) {
                        let m = e.to_string();
                        let cut: String = m.chars().take(300).collect();
                        failures.push(format!("{file}: {why}: {cut}"));
                    }
                }
                Ok(Ok((_, p))) => {
                    accepted += 1;
                    let st = &p.stability;
                    // Without particles the stable substep and the lightest particle are
                    // infinite by design (an empty body is a supported case); the speeds are
                    // always finite.
                    let particles: usize = p.bodies.iter().map(|b| b.x.len()).sum();
                    let limits = [st.dt_max, p.min_particle_mass];
                    let finite = [st.wave_speed, st.max_speed].iter().all(|x| x.is_finite())
                        && (particles == 0 || limits.iter().all(|x| x.is_finite()))
                        && p.bodies.iter().all(|b| {
                            b.x.iter().all(|x| x.is_finite())
                                && b.particle_mass.is_finite()
                                && b.particle_mass > 0.0
                        });
                    if !finite {
                        failures.push(format!(
                            "{file}: accepted with a non-finite number: {st:?}, particle mass {}",
                            p.min_particle_mass
                        ));
                    }
                }
            }
        }
    }
    eprintln!(
        "{accepted} accepted, {refused} refused, {} failures",
        failures.len()
    );
    assert!(
        failures.is_empty(),
        "{} of {} cases failed:\n{}",
        failures.len(),
        accepted + refused,
        failures.join("\n")
    );
    // The mutations reach past the parser: some cases are accepted and some refused by the
    // checks behind it.
    assert!(
        accepted > 100 && refused > 1000,
        "{accepted} accepted, {refused} refused"
    );
}
