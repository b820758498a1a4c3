//! Learning a skill from a demonstration (seed B, §2.1): the demonstration format
//! ([`format`]), synthetic demonstrations ([`make`]), the spoon's pose tracked in each frame by
//! differentiable silhouettes ([`track`]), Θ fitted to the tracked path ([`skill_fit`]), and
//! the whole fit ([`fit`]).

pub mod fit;
pub mod format;
pub mod make;
pub mod skill_fit;
pub mod track;
