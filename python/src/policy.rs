//! The policy dataset's unit of work for Python: `powderlab.distributed.map_dataset` runs one
//! randomised scene per Ray task with these, and gathers the results as `powderlab policy
//! dataset` does, into the same files.

use crate::{to_py, Scene};
use powderlab::lab::policy::dataset::{self, Config};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use std::path::PathBuf;

fn config_of(text: &str) -> PyResult<Config> {
    serde_json::from_str(text)
        .map_err(|e| PyValueError::new_err(format!("not a policy dataset config: {e}")))
}

/// The settings of a dataset of `scene` (JSON), as `powderlab policy dataset` makes them from
/// its options.
#[pyfunction]
#[pyo3(signature = (scene, scenes = 160, budget = 10, augment = 2, augment_steps = 1, perturb = 0.1, seed = 0))]
pub fn policy_dataset_config(
    scene: &Scene,
    scenes: usize,
    budget: usize,
    augment: usize,
    augment_steps: usize,
    perturb: f64,
    seed: u64,
) -> PyResult<String> {
    dataset::spec_of(&scene.inner).map_err(to_py)?;
    let cfg = Config {
        scene_hash: scene.inner.fingerprint(),
        scenes,
        budget,
        augment,
        augment_steps,
        perturb,
        seed,
    };
    serde_json::to_string(&cfg).map_err(|e| PyValueError::new_err(e.to_string()))
}

/// Makes `dir` a folder of the dataset `config` (writes its settings, or checks those there).
#[pyfunction]
pub fn policy_dataset_claim(dir: PathBuf, config: &str) -> PyResult<()> {
    dataset::claim(&dir, &config_of(config)?).map_err(to_py)
}

/// Scene `k`'s samples, as the JSON text the CLI keeps in `scene-K.json`, computed with
/// `threads` worker threads; the GIL is released meanwhile.
#[pyfunction]
#[pyo3(signature = (scene, config, k, threads = 1))]
pub fn policy_dataset_scene(
    py: Python<'_>,
    scene: &Scene,
    config: &str,
    k: usize,
    threads: usize,
) -> PyResult<String> {
    let cfg = config_of(config)?;
    let owned = scene.inner.clone();
    py.detach(move || -> anyhow::Result<String> {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads.max(1))
            .build()?;
        let samples = pool.install(|| dataset::scene_samples(&owned, &cfg, k))?;
        dataset::scene_text(&samples)
    })
    .map_err(to_py)
}

/// The path of scene `k`'s file in `dir`.
#[pyfunction]
pub fn policy_dataset_scene_file(dir: PathBuf, k: usize) -> String {
    dataset::scene_file(&dir, k).display().to_string()
}

/// Gathers `dir`'s scene files into `dir/dataset.safetensors` (running here any scene still
/// missing) and returns its path.
#[pyfunction]
pub fn policy_dataset_write(
    py: Python<'_>,
    scene: &Scene,
    config: &str,
    dir: PathBuf,
) -> PyResult<String> {
    let cfg = config_of(config)?;
    let owned = scene.inner.clone();
    py.detach(move || -> anyhow::Result<String> {
        let samples = dataset::generate(&owned, &cfg, &dir, &|_| {})?;
        let path = dir.join("dataset.safetensors");
        dataset::write(&path, &samples)?;
        Ok(path.display().to_string())
    })
    .map_err(to_py)
}
