//! The policy's files: its safetensors files (metadata and tensors, refusing a file of another
//! kind by its `format` tag) and the JSON pieces each long step keeps so that it resumes.

use candle_core::{DType, Device, Tensor};
use std::collections::HashMap;
use std::path::Path;

/// A safetensors file's metadata and tensors (f64, on the CPU), refusing another `format`.
pub fn open(
    path: &Path,
    bytes: &[u8],
    format: &str,
) -> anyhow::Result<(HashMap<String, String>, HashMap<String, Tensor>)> {
    let bad = |what: String| anyhow::anyhow!("{}: {what}", path.display());
    let (_, m) = safetensors::SafeTensors::read_metadata(bytes)
        .map_err(|e| bad(format!("not a safetensors file ({e})")))?;
    let meta = m.metadata().clone().unwrap_or_default();
    let found = meta.get("format").map_or("none", String::as_str);
    if found != format {
        return Err(bad(format!(
            "field metadata.format: '{found}', expected '{format}'; write it with the matching \
             `powderlab policy` command"
        )));
    }
    let t = candle_core::safetensors::load_buffer(bytes, &Device::Cpu)
        .map_err(|e| bad(format!("reading its tensors: {e}")))?;
    let t = t
        .into_iter()
        .map(|(k, v)| Ok((k, v.to_dtype(DType::F64)?)))
        .collect::<candle_core::Result<_>>()?;
    Ok((meta, t))
}

/// The value kept as JSON in `path` when it reads back and `valid` accepts it; otherwise
/// `make`'s, written there atomically. Every long step of the policy (the dataset's scenes, the
/// fine-tune's episodes, the evaluation's trials) keeps its pieces this way, so a rerun after a kill redoes only the piece it was working on.
pub fn kept<T: serde::Serialize + serde::de::DeserializeOwned>(
    path: &Path,
    valid: impl FnOnce(&T) -> bool,
    make: impl FnOnce() -> anyhow::Result<T>,
) -> anyhow::Result<T> {
    if let Some(t) = std::fs::read_to_string(path)
        .ok()
        .and_then(|s| serde_json::from_str::<T>(&s).ok())
        .filter(|t| valid(t))
    {
        return Ok(t);
    }
    let t = make()?;
    crate::util::write_atomic(path, serde_json::to_string(&t)?.as_bytes())?;
    Ok(t)
}

/// Writes `stamp` (what a run's results depend on) to `path`, or, when `path` holds another,
/// refuses the folder: its results, `what`, belong to other settings; `flag` names the option
/// that chooses the folder.
pub fn stamped(
    path: &Path,
    stamp: &serde_json::Value,
    what: &str,
    flag: &str,
) -> anyhow::Result<()> {
    match std::fs::read_to_string(path) {
        Ok(t) if serde_json::from_str::<serde_json::Value>(&t).ok().as_ref() != Some(stamp) => {
            anyhow::bail!(
                "{}: this folder holds {what} of other settings or another scene file; rerun \
                 with the same ones, or choose another {flag}",
                path.display()
            )
        }
        Ok(_) => Ok(()),
        Err(_) => Ok(crate::util::write_atomic(
            path,
            serde_json::to_string_pretty(stamp)?.as_bytes(),
        )?),
    }
}
