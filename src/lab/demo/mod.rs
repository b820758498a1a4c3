//! Learning a skill from a demonstration (seed B, §2.1): the demonstration format
//! ([`format`]), synthetic demonstrations ([`make`]), the spoon's pose tracked in each frame by
//! differentiable silhouettes ([`track`]), Θ fitted to the tracked path ([`skill_fit`]), and
//! the whole fit ([`fit`]), with the spoon's shape ([`shape`]) and a demonstrator's spoon carried
//! over to the robot's ([`spoon_map`]); a Rerun recording of the track over the frames
//! (`overlay`).

pub mod fit;
pub mod format;
pub mod make;
#[cfg(feature = "rerun")]
pub mod overlay;
pub mod shape;
pub mod skill_fit;
pub mod spoon_map;
pub(crate) mod study;
pub mod track;
