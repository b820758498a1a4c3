//! # powderlab
//!
//! Differentiable 3D MLS-MPM simulation of powders and granular media, for optimising robot
//! skills (scooping, transporting, pouring) by gradient descent through the physics.
//!
//! ## One substep
//!
//! Each stage is a bevy_ecs system in its own file under [`systems`], run in chained system
//! sets (see [`systems::Stage`]):
//!
//! 1. **grid reset**: zero grid mass and momentum;
//! 2. **deformation update**: `F_tmp = (I + Δt·C)·F`;
//! 3. **SVD**: `F_tmp = U·Σ·Vᵀ`, robust for near-equal and tiny singular values;
//! 4. **constitutive model**: the material plug-in's return mapping gives `F′` and the
//!    Kirchhoff stress (Drucker–Prager sand: StVK in Hencky strain, Klár et al. 2016);
//! 5. **P2G**: race-free, fixed-order APIC/MLS-MPM scatter with quadratic B-splines;
//! 6. **tool move**: kinematic tools advance by `u/N_sub`;
//! 7. **gravity**: `v_i += Δt·g`;
//! 8. **grid collision**: SDF colliders with Coulomb friction, then domain walls;
//! 9. **G2P**: gather `v` and the affine `C`;
//! 10. **particle collision**: projects particle velocities against thin walls so they never
//!     leak;
//! 11. **advect**: `x += Δt·v`.
//!
//! The schedule holds only what the scene needs ([`systems::SubstepPlan`]). Pure maths lives in
//! [`math`]; the driver is [`sim::Simulation`].
//!
//! ## Gradients
//!
//! Each stage has a mirrored adjoint system in [`adjoint`] (same file name, `_adjoint` suffix),
//! run in the reverse stage order by a checkpointed backward pass ([`adjoint::tape::gradient`]).
//! It differentiates a loss on the final positions with respect to the initial state, the
//! material parameters, collider friction, gravity and the tools' controls, start poses and
//! skill parameters; `powderlab gradcheck` compares each against central differences.

/// The scalar type of the simulation. Everything runs in f64: gradient checks need it, and the
/// forward pass shares the same code.
pub type Real = f64;

pub mod adjoint;
pub mod components;
pub mod error;
#[cfg(feature = "lab")]
pub mod lab;
pub mod materials;
pub mod math;
pub mod metrics;
pub mod nonfinite;
pub mod plugin;
pub mod ply;
#[cfg(feature = "rerun")]
pub mod record;
pub mod rollout;
pub mod scene;
pub mod sim;
pub mod skills;
pub mod systems;
pub mod util;
