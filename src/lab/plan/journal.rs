//! The rollouts of a plan, one JSON line each, keyed by the node's path and the action's bits:
//! a plan killed and run again finds what it had instead of simulating it again. A line cut
//! short by the kill does not parse and is dropped.

use anyhow::Context;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::io::Write;
use std::path::Path;

/// Hears of every rollout of a plan: the rollouts so far and a message.
pub type Progress = Box<dyn FnMut(usize, &str) + Send>;

/// One rollout as the journal keeps it.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Entry {
    pub key: String,
    pub loss: f64,
    /// What the task measures at the end (grams delivered, the fraction in the region).
    pub value: f64,
    pub particle_substeps: f64,
}

/// The journal: what was read, and the file new rollouts go to (none: kept in memory only).
#[derive(Default)]
pub struct Journal {
    map: HashMap<String, Entry>,
    file: Option<std::fs::File>,
}

impl Journal {
    /// Reads `path` if it exists and appends to it from now on.
    pub fn open(path: &Path) -> anyhow::Result<Journal> {
        let mut map = HashMap::new();
        if let Ok(text) = std::fs::read_to_string(path) {
            for line in text.lines() {
                if let Ok(e) = serde_json::from_str::<Entry>(line) {
                    map.insert(e.key.clone(), e);
                }
            }
        }
        let file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
            .with_context(|| format!("opening the journal {}", path.display()))?;
        Ok(Journal {
            map,
            file: Some(file),
        })
    }

    pub fn get(&self, key: &str) -> Option<&Entry> {
        self.map.get(key)
    }

    /// Records a rollout (written and flushed before it counts).
    pub fn put(&mut self, e: Entry) -> anyhow::Result<()> {
        if let Some(f) = &mut self.file {
            writeln!(f, "{}", serde_json::to_string(&e)?)?;
            f.flush()?;
        }
        self.map.insert(e.key.clone(), e);
        Ok(())
    }
}

/// The key of an action from a node: the node's path and the action's bits.
pub fn key(node: &str, action: &[f64]) -> String {
    let bits: Vec<String> = action
        .iter()
        .map(|t| format!("{:016x}", t.to_bits()))
        .collect();
    format!("{node}|{}", bits.join(","))
}

/// A seed for a node's optimiser from the run's seed and the node's path, so a resumed plan
/// draws the same samples.
pub fn node_seed(seed: u64, node: &str) -> u64 {
    seed ^ u64::from_str_radix(&crate::util::fnv1a(node), 16).expect("fnv1a gives hex")
}
