//! The calibration's journal: every rollout appended as it finishes, read back on a resume.

use super::{Calibration, Eval};
use serde::{Deserialize, Serialize};

/// The rollouts of a calibration run, appended one JSON line each to a file as they finish, so
/// that a killed run resumes where it stopped: a rollout already in the file (same method, index
/// and pass, and bitwise the same `u`) is read back instead of run.
pub struct Journal {
    file: Option<crate::lab::journal::Journal<Line>>,
    done: std::collections::HashMap<(String, usize, bool), Eval>,
    /// Rollouts read back instead of run.
    pub replayed: usize,
}

#[derive(Serialize, Deserialize)]
struct Line {
    method: String,
    index: usize,
    eval: Eval,
}

impl Journal {
    /// A journal that keeps nothing (tests, studies that keep their own).
    pub fn none() -> Journal {
        Journal {
            file: None,
            done: Default::default(),
            replayed: 0,
        }
    }

    /// Opens (or creates) the journal at `path`, reading what it holds. A torn last line (a
    /// kill mid-write) is dropped.
    pub fn open(path: &std::path::Path) -> anyhow::Result<Journal> {
        let (file, lines) = crate::lab::journal::Journal::<Line>::open(path)?;
        let mut done = std::collections::HashMap::new();
        for line in lines {
            let grad = line.eval.grad.is_some();
            done.insert((line.method, line.index, grad), line.eval);
        }
        Ok(Journal {
            file: Some(file),
            done,
            replayed: 0,
        })
    }

    /// The rollout `index` of `method` at `u`: read back, or run and appended.
    pub fn eval(
        &mut self,
        cal: &Calibration,
        method: &str,
        index: usize,
        u: &[f64],
        grad: bool,
    ) -> anyhow::Result<Eval> {
        if let Some(e) = self.lookup(method, index, u, grad) {
            return Ok(e);
        }
        let e = cal.evaluate(u, grad)?;
        self.record(method, index, &e)?;
        Ok(e)
    }

    /// The journal's rollout `index` of `method`, if it ran at bitwise this `u` and pass.
    pub fn lookup(&mut self, method: &str, index: usize, u: &[f64], grad: bool) -> Option<Eval> {
        let e = self.done.get(&(method.to_string(), index, grad))?;
        let same =
            e.u.len() == u.len() && e.u.iter().zip(u).all(|(a, b)| a.to_bits() == b.to_bits());
        if same {
            self.replayed += 1;
            Some(e.clone())
        } else {
            None
        }
    }

    /// Appends a finished rollout.
    pub fn record(&mut self, method: &str, index: usize, e: &Eval) -> anyhow::Result<()> {
        if let Some(f) = &self.file {
            f.append(&Line {
                method: method.into(),
                index,
                eval: e.clone(),
            })?;
        }
        self.done
            .insert((method.to_string(), index, e.grad.is_some()), e.clone());
        Ok(())
    }
}
