//! The rollouts of a plan, one JSON line each, keyed by the node's path and the action's bits:
//! a plan killed and run again finds what it had instead of simulating it again. A line cut
//! short by the kill is cut off (`lab::journal`).

use serde::{Deserialize, Serialize};
use std::collections::HashMap;
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
    /// A push stroke's push loss, where its rollout had a backward pass.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub push_loss: Option<f64>,
    /// A push stroke's `∂(push loss)/∂Φ`, where its rollout had a backward pass.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grad: Option<[f64; 5]>,
}

/// The journal: what was read, and the file new rollouts go to (none: kept in memory only).
#[derive(Default)]
pub struct Journal {
    map: HashMap<String, Entry>,
    file: Option<crate::lab::journal::Journal<Entry>>,
}

impl Journal {
    /// Reads `path` if it exists and appends to it from now on.
    pub fn open(path: &Path) -> anyhow::Result<Journal> {
        let (file, entries) = crate::lab::journal::Journal::<Entry>::open(path)?;
        Ok(Journal {
            map: entries.into_iter().map(|e| (e.key.clone(), e)).collect(),
            file: Some(file),
        })
    }

    pub fn get(&self, key: &str) -> Option<&Entry> {
        self.map.get(key)
    }

    /// Records a rollout (written and synced before it counts).
    pub fn put(&mut self, e: Entry) -> anyhow::Result<()> {
        if let Some(f) = &self.file {
            f.append(&e)?;
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
