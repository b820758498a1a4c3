//! Stage 4, constitutive model: the material's update in principal space gives the new
//! `F = U·diag(σ′)·Vᵀ` (or keeps `F_tmp` when the material has no plasticity) and the Kirchhoff
//! stress `τ = U·diag(τ_p)·Uᵀ`, folded into the MLS-MPM affine term
//! `A_p = m_p·C_p − Δt·V_p·(4/dx²)·τ_p`.
//!
//! One instance of [`constitutive_model`] runs per material plug-in in the scene.
//! Reads `SvdFactors`, `TrialDeformation`, `AffineVelocity`, the material; writes
//! `DeformationGradient`, `P2gAffine`, `Hardening`; reports non-finite stress to `Health`.

use crate::components::*;
use crate::materials::Material;
use crate::systems::FiniteWatch;
use bevy_ecs::prelude::*;
use glam::{DMat3, DVec3};
use rayon::prelude::*;

/// Reassembles `U·diag(d)·Wᵀ`.
#[inline(always)]
pub fn compose(u: DMat3, d: DVec3, w: DMat3) -> DMat3 {
    DMat3::from_cols(u.x_axis * d.x, u.y_axis * d.y, u.z_axis * d.z) * w.transpose()
}

/// The P2G stress factor `−Δt·V_p·4/dx²` of a body.
#[inline(always)]
pub fn stress_coef(dt: f64, particle_volume: f64, dx: f64) -> f64 {
    -dt * particle_volume * 4.0 * (1.0 / (dx * dx))
}

/// The MLS-MPM affine term `A_p = m_p·C_p + coef·U·diag(τ_p)·Uᵀ` (`coef` from [`stress_coef`]).
/// The backward pass rebuilds `A_p` with this same function from what it recorded.
#[inline(always)]
pub fn p2g_affine(u: DMat3, tau_p: DVec3, c: DMat3, coef: f64, mass: f64) -> DMat3 {
    compose(u, tau_p, u) * coef + c * mass
}

/// Particles one task of the stage updates (a multiple of the materials' lane widths).
const CHUNK: usize = 64;

#[allow(clippy::type_complexity)]
pub fn constitutive_model<M: Material>(
    params: Res<SimParams>,
    grid: Res<Grid>,
    mut health: ResMut<Health>,
    mut bodies: Query<(
        &M,
        &Body,
        &SvdFactors,
        &TrialDeformation,
        &AffineVelocity,
        &mut DeformationGradient,
        &mut P2gAffine,
        Option<&mut Hardening>,
        Option<(&mut UpdateSaved, &mut PrincipalStress)>,
    )>,
) {
    let dt = params.dt_sub;
    for (mat, body, svd, ft, c, mut f, mut aff, hard, saved) in &mut bodies {
        let coef = stress_coef(dt, body.particle_volume, grid.dx);
        let mass = body.particle_mass;
        let watch = FiniteWatch::default();
        // One chunk of particles: the material's update of them all (in vector registers where
        // the material has them), then `F` and `A_p` of each.
        let update = |k: usize,
                      q: Option<&mut [f64]>,
                      saved: Option<(&mut [crate::materials::Saved], &mut [DVec3])>,
                      f_out: &mut [DMat3],
                      a_out: &mut [DMat3]| {
            let (i0, n) = (k * CHUNK, f_out.len());
            let mut no_hardening = [0.0; CHUNK];
            let q = q.unwrap_or(&mut no_hardening[..n]);
            let mut updated = [(None, DVec3::ZERO); CHUNK];
            let (sv, mut tau_out) = saved.unzip();
            mat.update_many(crate::materials::Group {
                sigma: &svd.s[i0..i0 + n],
                q,
                saved: sv,
                out: &mut updated[..n],
            });
            for (l, &(s_new, tau_p)) in updated[..n].iter().enumerate() {
                let i = i0 + l;
                if let Some(t) = tau_out.as_deref_mut() {
                    t[l] = tau_p;
                }
                f_out[l] = match s_new {
                    Some(s) => compose(svd.u[i], s, svd.v[i]),
                    None => ft.0[i],
                };
                a_out[l] = p2g_affine(svd.u[i], tau_p, c.0[i], coef, mass);
                watch.check(f_out[l].is_finite() && a_out[l].is_finite());
            }
        };
        if let Some((sv, st)) = &saved {
            // The zip below would silently skip particles past a short buffer.
            assert_eq!(sv.0.len(), svd.s.len(), "UpdateSaved sized for its body");
            assert_eq!(
                st.0.len(),
                svd.s.len(),
                "PrincipalStress sized for its body"
            );
        }
        let fa =
            f.0.par_chunks_mut(CHUNK)
                .zip(aff.0.par_chunks_mut(CHUNK))
                .enumerate();
        match (hard, saved) {
            (Some(mut h), Some((mut sv, mut st))) => fa
                .zip(
                    h.0.par_chunks_mut(CHUNK)
                        .zip(sv.0.par_chunks_mut(CHUNK).zip(st.0.par_chunks_mut(CHUNK))),
                )
                .for_each(|((k, (fo, ao)), (q, (s, t)))| update(k, Some(q), Some((s, t)), fo, ao)),
            (Some(mut h), None) => fa
                .zip(h.0.par_chunks_mut(CHUNK))
                .for_each(|((k, (fo, ao)), q)| update(k, Some(q), None, fo, ao)),
            (None, Some((mut sv, mut st))) => fa
                .zip(sv.0.par_chunks_mut(CHUNK).zip(st.0.par_chunks_mut(CHUNK)))
                .for_each(|((k, (fo, ao)), (s, t))| update(k, None, Some((s, t)), fo, ao)),
            (None, None) => fa.for_each(|(k, (fo, ao))| update(k, None, None, fo, ao)),
        }
        for (field, idx) in [
            ("F", watch.first_nonfinite_mat(&f.0)),
            ("stress", watch.first_nonfinite_mat(&aff.0)),
        ] {
            if let Some(i) = idx {
                let value = if field == "F" { f.0[i] } else { aff.0[i] };
                health.report(Fault::particle("constitutive", field, &body.name, i, value));
            }
        }
    }
}
