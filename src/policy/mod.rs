//! A skill policy over randomised scenes (seed B's Sim2Real step, docs/design.md §13):
//!
//! - [`features`]: what the policy sees of a scene;
//! - [`dataset`]: randomised scenes with their optimised Θ\*, and seed B's augmentation;
//! - [`anchor`]: the labels searched again from the distilled policy's Θ, so that they lie in
//!   one basin;
//! - [`file`]: reading their safetensors files;
//! - [`net`]: the MLP from features to Θ (candle), its fit and its safetensors file;
//! - [`reinforce`]: the fine-tune, REINFORCE with a baseline, and [`tune`], its episodes as
//!   rollouts rewarded with −L;
//! - [`eval`]: the policy against a random Θ and the per-scene optimiser on held-out scenes.

pub mod anchor;
pub mod dataset;
pub mod eval;
pub mod features;
pub mod file;
pub mod net;
pub mod reinforce;
pub mod tune;
