//! Per-body particle columns.

use bevy_ecs::prelude::*;
use glam::{DMat3, DVec3};

/// A body of particles sharing one material.
#[derive(Component, Clone, Debug)]
pub struct Body {
    pub name: String,
    /// Position of the body in the scene file; systems visit bodies in this order.
    pub index: usize,
    /// Mass of one particle (kg).
    pub particle_mass: f64,
    /// Initial volume of one particle (m³).
    pub particle_volume: f64,
    /// Lamé parameters (μ, λ) of the body's material (Pa), for the elastic energy.
    pub lame: (f64, f64),
}

/// Particle positions `x` (m). State.
#[derive(Component, Clone, Debug, Default)]
pub struct Position(pub Vec<DVec3>);

/// Particle velocities `v` (m/s). State.
#[derive(Component, Clone, Debug, Default)]
pub struct Velocity(pub Vec<DVec3>);

/// APIC affine velocity `C` (1/s), the MLS-MPM velocity gradient. State.
#[derive(Component, Clone, Debug, Default)]
pub struct AffineVelocity(pub Vec<DMat3>);

/// Elastic deformation gradient `F` after the return mapping. State.
#[derive(Component, Clone, Debug, Default)]
pub struct DeformationGradient(pub Vec<DMat3>);

/// Accumulated plastic strain `q` (Klár 2016 hardening). State; only present on bodies whose
/// material hardens.
#[derive(Component, Clone, Debug, Default)]
pub struct Hardening(pub Vec<f64>);

/// Trial deformation gradient `F_tmp = (I + Δt·C)·F`. Scratch.
#[derive(Component, Clone, Debug, Default)]
pub struct TrialDeformation(pub Vec<DMat3>);

/// SVD factors of the trial deformation gradient. Scratch.
#[derive(Component, Clone, Debug, Default)]
pub struct SvdFactors {
    pub u: Vec<DMat3>,
    pub s: Vec<DVec3>,
    pub v: Vec<DMat3>,
}

/// What a material's update computed that its adjoint would otherwise compute again (for
/// Drucker–Prager: the Hencky strain, the projected strain and its exponential), per particle.
/// Present only while a backward pass recomputes: the tape inserts it, the constitutive stage
/// fills it through `Material::update_saving`, the records keep it per substep, and the
/// adjoint reads it instead of redoing the logarithms and exponentials. Scratch.
#[derive(Component, Clone, Debug, Default)]
pub struct UpdateSaved(pub Vec<crate::materials::Saved>);

/// The principal Kirchhoff stress `τ_p` of each particle's update. Present only while a backward
/// pass recomputes (inserted with [`UpdateSaved`]): the substep records keep these 24 bytes per
/// particle instead of the 72-byte [`P2gAffine`], which they rebuild from it, `U` and `C` with
/// the forward's own function (`systems::constitutive::p2g_affine`), to the bit. Scratch.
#[derive(Component, Clone, Debug, Default)]
pub struct PrincipalStress(pub Vec<DVec3>);

/// MLS-MPM affine matrix scattered by P2G: `m_p·C_p − Δt·V_p·(4/dx²)·τ_p`. Scratch.
#[derive(Component, Clone, Debug, Default)]
pub struct P2gAffine(pub Vec<DMat3>);

/// Particle order for the race-free P2G scatter: particle indices bucketed by x-slab of the
/// grid, and the start of each slab's bucket. Scratch, reused between substeps.
#[derive(Component, Clone, Debug, Default)]
pub struct ScatterOrder {
    pub order: Vec<u32>,
    pub slab_start: Vec<u32>,
    /// Per fixed chunk of particles, the count of each slab (chunk-major), then the running
    /// insertion cursors.
    pub counts: Vec<u32>,
    /// Each particle's slab.
    pub slab: Vec<u32>,
}

/// The full particle state of one body, for snapshots, PLY output and tests.
#[derive(Clone, Debug, PartialEq)]
pub struct BodyState {
    pub name: String,
    pub x: Vec<DVec3>,
    pub v: Vec<DVec3>,
    pub c: Vec<DMat3>,
    pub f: Vec<DMat3>,
}

/// FNV-1a over the bits of every particle's x, v, C and F: equal exactly when two runs end in
/// the same state to the bit (how `bench` and the growth study show that a speed lever left
/// the results alone).
pub fn state_fingerprint(states: &[BodyState]) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    let mut eat = |x: f64| {
        for b in x.to_bits().to_le_bytes() {
            h = (h ^ b as u64).wrapping_mul(0x0100_0000_01b3);
        }
    };
    for b in states {
        for (x, v) in b.x.iter().zip(&b.v) {
            x.to_array()
                .into_iter()
                .chain(v.to_array())
                .for_each(&mut eat);
        }
        for (c, f) in b.c.iter().zip(&b.f) {
            c.to_cols_array()
                .into_iter()
                .chain(f.to_cols_array())
                .for_each(&mut eat);
        }
    }
    h
}
