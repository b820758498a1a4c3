//! The run journal: one JSON line per finished rollout, appended and synced to disk before the
//! next rollout is used. It is what makes `optimize --resume` lose nothing.
//!
//! Every method is deterministic given its seed (Θ_init, CMA-ES sampling, SAC's network
//! initialisation and noise all come from fixed seeds, and a rollout is bitwise reproducible for
//! any thread count). A resumed run therefore re-executes the methods from the start and asks
//! the journal before each rollout: a rollout already recorded, with bitwise the same Θ, is
//! replayed from the journal instead of simulated. A kill loses at most the rollouts in flight;
//! a torn last line (killed mid-write) is cut off on resume (`lab::journal`, the store every
//! resumable command shares).

use super::problem::Outcome;
use super::Method;
use crate::skills::Theta;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

/// One finished rollout.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Record {
    pub method: Method,
    pub seed: usize,
    /// The batch the rollout belongs to: the epoch for `grad` and `sac` (one rollout each),
    /// the generation for `cmaes`, the draw for `random`.
    pub batch: usize,
    pub theta: Theta,
    /// What the rollout gave (its fields sit flat beside the ones above in the JSON line).
    #[serde(flatten)]
    pub outcome: Outcome,
    /// Seconds the method had been running when this rollout finished, summed over every
    /// process that worked on this output directory (a resumed run starts from the largest
    /// value its journal holds). Absent in journals written before it existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub method_elapsed_s: Option<f64>,
}

type Key = (Method, usize, usize, [u64; 5]);

fn key(method: Method, seed: usize, batch: usize, theta: &Theta) -> Key {
    (method, seed, batch, theta.map(f64::to_bits))
}

/// The journal of one run directory.
pub struct Journal {
    file: crate::lab::journal::Journal<Record>,
    known: HashMap<Key, Record>,
    replayed: AtomicUsize,
    ran: AtomicUsize,
}

impl Journal {
    /// Opens `path`: a new, empty journal unless `resume`, in which case the finished rollouts
    /// it holds are loaded (a torn last line is cut off).
    pub fn open(path: &Path, resume: bool) -> anyhow::Result<Journal> {
        let (file, records): (_, Vec<Record>) = if resume {
            crate::lab::journal::Journal::open(path)?
        } else {
            (crate::lab::journal::Journal::create(path)?, Vec::new())
        };
        let known = records
            .into_iter()
            .map(|r| (key(r.method, r.seed, r.batch, &r.theta), r))
            .collect();
        Ok(Journal {
            file,
            known,
            replayed: AtomicUsize::new(0),
            ran: AtomicUsize::new(0),
        })
    }

    pub fn path(&self) -> &Path {
        self.file.path()
    }

    /// The recorded rollout for this method, seed, batch and Θ (bitwise), if any.
    pub fn replay(
        &self,
        method: Method,
        seed: usize,
        batch: usize,
        theta: &Theta,
    ) -> Option<Record> {
        let r = self.known.get(&key(method, seed, batch, theta)).cloned();
        if r.is_some() {
            self.replayed.fetch_add(1, Ordering::Relaxed);
        }
        r
    }

    /// Appends a finished rollout and syncs it to disk.
    pub fn append(&self, r: &Record) -> anyhow::Result<()> {
        self.file.append(r)?;
        self.ran.fetch_add(1, Ordering::Relaxed);
        Ok(())
    }

    /// The method's running time carried over from the processes that wrote this journal
    /// before (0 for a fresh journal): the largest `method_elapsed_s` among its rollouts.
    pub fn carried_elapsed(&self, method: Method) -> f64 {
        self.known
            .values()
            .filter(|r| r.method == method)
            .filter_map(|r| r.method_elapsed_s)
            .fold(0.0, f64::max)
    }

    /// Rollouts replayed from the journal and rollouts simulated by this process.
    pub fn counts(&self) -> (usize, usize) {
        (
            self.replayed.load(Ordering::Relaxed),
            self.ran.load(Ordering::Relaxed),
        )
    }
}
