//! The one journal of every resumable command: an append-only file of JSON lines, one finished
//! piece of work (a rollout, a case) each, read back on a resume so that nothing done is done
//! again.
//!
//! - **Durable.** Each line is written whole and synced to disk (`sync_data`) before
//!   [`Journal::append`] returns, so what a caller counts as done survives a kill or a crash.
//! - **Torn-line recovery.** A kill mid-write leaves a last line without its newline. Opening
//!   the journal cuts that tail off the file (and syncs the cut) before anything is appended, so
//!   a new line is never glued to a torn one.
//! - **Refuses what it cannot read.** A complete line that does not parse (an edited file, or
//!   one another version wrote) is an error naming the file and line, never skipped: skipping
//!   would silently redo, or worse mis-key, the work it held.
//!
//! What a record is keyed by is the caller's: the lab keys by what fixes a result, the parsed
//! scene ([`crate::scene::Scene::fingerprint`]) and the settings, never a file's text.

use anyhow::{bail, Context};
use serde::de::DeserializeOwned;
use serde::Serialize;
use std::fs::{File, OpenOptions};
use std::io::Write;
use std::marker::PhantomData;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// An append-only journal of records `T` (see the module docs).
pub struct Journal<T> {
    path: PathBuf,
    file: Mutex<File>,
    _record: PhantomData<fn(&T)>,
}

/// The records of a journal's text and the length of its complete lines (a torn last line, one
/// without its newline, is not counted). A complete line that does not parse is an error.
fn parse<T: DeserializeOwned>(path: &Path, text: &str) -> anyhow::Result<(Vec<T>, usize)> {
    let mut records = Vec::new();
    let mut good = 0usize;
    for (n, line) in text.split_inclusive('\n').enumerate() {
        let Some(body) = line.strip_suffix('\n') else {
            break; // torn: the kill came before its newline
        };
        if !body.trim().is_empty() {
            match serde_json::from_str::<T>(body) {
                Ok(r) => records.push(r),
                Err(e) => bail!(
                    "{}:{}: a journal line that does not parse ({e}); the file was edited or \
                     written by another version: move it aside to start afresh",
                    path.display(),
                    n + 1
                ),
            }
        }
        good += line.len();
    }
    Ok((records, good))
}

/// The records of the journal at `path` (none if there is no file), without opening it to
/// append: what a page reads to regenerate. A torn last line is left out.
pub fn read<T: DeserializeOwned>(path: &Path) -> anyhow::Result<Vec<T>> {
    match std::fs::read_to_string(path) {
        Ok(text) => Ok(parse(path, &text)?.0),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(Vec::new()),
        Err(e) => Err(e).with_context(|| format!("cannot read the journal {}", path.display())),
    }
}

impl<T: Serialize + DeserializeOwned> Journal<T> {
    /// Opens the journal at `path` to go on with it, creating it if need be, and returns the
    /// records it holds. A torn last line is cut off the file first.
    pub fn open(path: &Path) -> anyhow::Result<(Journal<T>, Vec<T>)> {
        let mut records = Vec::new();
        if path.exists() {
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("cannot read the journal {}", path.display()))?;
            let (r, good) = parse(path, &text)?;
            records = r;
            if good < text.len() {
                let f = OpenOptions::new().write(true).open(path)?;
                f.set_len(good as u64)?;
                f.sync_all()?;
            }
        }
        Ok((Self::append_to(path, false)?, records))
    }

    /// A new, empty journal at `path` (an old one there is emptied).
    pub fn create(path: &Path) -> anyhow::Result<Journal<T>> {
        Self::append_to(path, true)
    }

    fn append_to(path: &Path, truncate: bool) -> anyhow::Result<Journal<T>> {
        let file = OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
            .with_context(|| format!("cannot open the journal {}", path.display()))?;
        if truncate {
            file.set_len(0)?;
        }
        Ok(Journal {
            path: path.to_path_buf(),
            file: Mutex::new(file),
            _record: PhantomData,
        })
    }

    /// Appends `record` as one line and syncs it to disk. Callers on several threads share one
    /// journal: each line is written whole under a lock.
    pub fn append(&self, record: &T) -> anyhow::Result<()> {
        let mut line = serde_json::to_string(record)?;
        line.push('\n');
        let mut f = self.file.lock().expect("journal lock");
        f.write_all(line.as_bytes())
            .and_then(|()| f.sync_data())
            .with_context(|| format!("cannot append to the journal {}", self.path.display()))
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Deserialize;

    #[derive(Debug, PartialEq, Serialize, Deserialize)]
    struct R {
        k: usize,
        x: f64,
    }

    fn dir() -> PathBuf {
        let d = std::env::temp_dir().join(format!(
            "powderlab-journal-{}-{:?}",
            std::process::id(),
            std::thread::current().id()
        ));
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn a_torn_line_is_cut_and_the_next_append_starts_clean() {
        let p = dir().join("torn.jsonl");
        {
            let j = Journal::<R>::create(&p).unwrap();
            j.append(&R { k: 1, x: 0.5 }).unwrap();
            j.append(&R { k: 2, x: 0.25 }).unwrap();
        }
        // A kill in the middle of the third line.
        let mut f = OpenOptions::new().append(true).open(&p).unwrap();
        f.write_all(br#"{"k":3,"x":0."#).unwrap();
        drop(f);
        assert_eq!(read::<R>(&p).unwrap().len(), 2);
        let (j, got) = Journal::<R>::open(&p).unwrap();
        assert_eq!(got, vec![R { k: 1, x: 0.5 }, R { k: 2, x: 0.25 }]);
        j.append(&R { k: 3, x: 0.125 }).unwrap();
        let (_, again) = Journal::<R>::open(&p).unwrap();
        assert_eq!(again.len(), 3);
        assert_eq!(again[2], R { k: 3, x: 0.125 });
    }

    #[test]
    fn a_complete_line_that_does_not_parse_is_refused_with_its_place() {
        let p = dir().join("bad.jsonl");
        std::fs::write(&p, "{\"k\":1,\"x\":0.5}\nnot json\n{\"k\":2,\"x\":1.0}\n").unwrap();
        let e = Journal::<R>::open(&p).err().unwrap().to_string();
        assert!(e.contains("bad.jsonl:2:"), "{e}");
        assert!(read::<R>(&p).is_err());
        // Nothing was cut from a file it refused.
        assert_eq!(std::fs::read_to_string(&p).unwrap().lines().count(), 3);
    }

    #[test]
    fn create_empties_and_a_missing_file_reads_as_empty() {
        let p = dir().join("fresh.jsonl");
        assert!(read::<R>(&p).unwrap().is_empty());
        std::fs::write(&p, "{\"k\":9,\"x\":9.0}\n").unwrap();
        let j = Journal::<R>::create(&p).unwrap();
        j.append(&R { k: 1, x: 1.0 }).unwrap();
        assert_eq!(read::<R>(&p).unwrap(), vec![R { k: 1, x: 1.0 }]);
    }
}
