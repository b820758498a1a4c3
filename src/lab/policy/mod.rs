//! A skill policy over randomised scenes (seed B's Sim2Real step, docs/design.md §13):
//!
//! - [`features`]: what the policy sees of a scene;
//! - [`dataset`]: randomised scenes with their labels Θ\*, seed B's augmentation and hindsight
//!   samples;
//! - [`knob`]: the dataset's labeller, a root search of the dose along one family of skills;
//! - [`file`]: reading their safetensors files;
//! - [`net`]: the MLP from features to Θ (candle), its fit and its safetensors file;
//! - [`reinforce`]: the fine-tune, REINFORCE with a baseline, and [`tune`], its episodes as
//!   rollouts rewarded with −L;
//! - [`eval`]: the policy against a random Θ and the per-scene optimiser on held-out scenes.

pub mod dataset;
pub mod eval;
pub mod features;
pub mod file;
pub mod knob;
pub mod net;
pub mod pour;
pub mod reinforce;
pub(crate) mod study;
pub mod tune;
