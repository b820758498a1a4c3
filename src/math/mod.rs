//! Pure maths: plain functions with no ECS or I/O, each testable on its own.
//!
//! Systems in `crate::systems` are thin wrappers that query components, call these functions
//! and write the results back. The adjoint twins (`*_adj`) will sit beside each function
//! (see `crate::adjoint`).

pub mod chamfer;
pub mod contact;
pub mod eigen;
pub mod elementary;
pub mod geometry;
pub mod heightfield;
pub mod kernel;
pub mod lanes;
pub mod mesh;
pub mod pose;
pub mod region;
pub mod return_map;
pub mod sdf;
pub mod simd;
pub mod svd;
