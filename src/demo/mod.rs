//! Learning a skill from a demonstration (seed B, §2.1): the spoon's pose tracked in each
//! frame by differentiable silhouettes ([`track`]).

pub mod skill_fit;
pub mod track;
