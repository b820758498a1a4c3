//! The lab: what is built on the simulator to learn and measure skills, apart from the
//! simulator itself (the cargo feature `lab`, on by default).
//!
//! - [`optim`]: skill optimisation by the adjoint's gradient and the baselines it is measured
//!   against;
//! - [`calibrate`]: a powder's parameters fitted to observations (seed A's DPSI step);
//! - [`demo`]: a skill learnt from a demonstration video (seed B §2.1);
//! - [`plan`]: sequences of scoops and strokes by A* (seed B §2.2);
//! - [`policy`]: a skill policy over randomised scenes (seed B's Sim2Real step);
//! - [`render`]: pictures of a run;
//! - [`repose`]: the angle of repose by a lifted-cylinder heap test;
//! - [`validate`]: checks against exact solutions and published experiments;
//! - [`weigh`]: milligram doses onto a balance, closed on its reading;
//! - [`gradcheck`]: the adjoint's gradients against central differences;
//! - [`study`]: the studies whose pages are `docs/results/`;
//! - [`journal`]: the one append-and-replay store of every resumable command;
//! - [`chart`]: the one chart setup of every figure;
//! - [`streams`]: the design and verdict streams of seeds and draws;
//! - [`stats`]: the statistics every page uses (mean ± sample sd, the paired tests, bootstrap).
//!
//! The simulator (`scene`, `sim`, `systems`, `adjoint`, `components`, `materials`, `math`,
//! `skills`, `rollout`, `record`) imports nothing from here;
//! `tests/module_graph_has_no_cycles.rs` checks it.

pub mod calibrate;
pub(crate) mod chart;
pub mod demo;
pub mod gradcheck;
pub(crate) mod journal;
pub mod optim;
pub mod plan;
pub mod policy;
pub mod render;
pub mod repose;
pub mod stats;
pub(crate) mod streams;
pub mod study;
pub mod validate;
pub mod weigh;
