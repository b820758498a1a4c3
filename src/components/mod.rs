//! ECS data: particle columns, the grid, colliders and simulation resources.
//!
//! Particle bodies are entities whose particles are held as structure-of-arrays columns
//! (one `Vec` per field), so systems run rayon over plain slices. State that defines the
//! simulation (positions, velocities, C, F, hardening) is kept apart from per-substep scratch
//! (trial F, SVD factors, P2G affine term, scatter order): only the former would be checkpointed.

pub mod adjoint;
pub mod balance;
pub mod collider;
pub mod grid;
pub mod parked;
pub mod particles;
pub mod sim;

pub use adjoint::*;
pub use balance::*;
pub use collider::*;
pub use grid::*;
pub use parked::{Cells, Parked};
pub use particles::*;
pub use sim::*;
