//! Adjoint of stage 4, the constitutive model. With `A = m·C + k·τ`, `k = −Δt·V_p·4/dx²`,
//! `τ = U·D·Uᵀ` (`D = diag(τ_p)`) and `F′ = U·diag(σ′)·Vᵀ` (or `F′ = F_tmp` without plasticity):
//!
//! ```text
//! C̄ += m·Ā;   τ̄ = k·Ā;   Ū += (τ̄ + τ̄ᵀ)·U·D;   D̄_a = (Uᵀ·τ̄·U)_aa
//! Ū += F̄′·V·diag(σ′);   V̄ += F̄′ᵀ·U·diag(σ′);   σ̄′_a = (Uᵀ·F̄′·V)_aa
//! ```
//!
//! then the material's `update_adj` maps `(σ̄′, D̄)` to `σ̄` and the parameter gradient
//! (exact within a return-mapping case, one-sided at the case switches); `update_adj_saved`
//! instead when the recomputed forward kept its [`UpdateSaved`] (the same bits, fewer
//! logarithms and exponentials). Consumes `Ā` and
//! `F̄′`; accumulates `Ū, σ̄, V̄`, `F̄_tmp`, `C̄` and [`MaterialAdj`].

use crate::adjoint::NonFiniteSeen;
use crate::components::*;
use crate::materials::Material;
use crate::systems::constitutive::compose;
use bevy_ecs::prelude::*;
use glam::{DMat3, DVec3};
use rayon::prelude::*;

/// Particles per chunk of the material-gradient reduction, each chunk one rayon task; fixed so
/// the sum order does not depend on the thread count. Small enough that the default scene's
/// 3,773 particles make 15 tasks. With chunks of 1,024 they made 4, and this stage took as
/// long on two threads as on one (1.59 s against 1.57 s in `bench scenes/powder_transport.ron
/// --backward --stages`); why the 4 did not split over the two threads was not measured.
const REDUCE_CHUNK: usize = 256;

#[inline(always)]
fn diag_of(m: DMat3) -> DVec3 {
    DVec3::new(m.x_axis.x, m.y_axis.y, m.z_axis.z)
}

#[allow(clippy::type_complexity)]
pub fn constitutive_model_adjoint<M: Material>(
    params: Res<SimParams>,
    grid: Res<Grid>,
    mut partial: Local<Vec<MaterialAdj>>,
    seen: Option<Res<NonFiniteSeen>>,
    mut bodies: Query<(
        &M,
        &Body,
        &SvdFactors,
        &mut SvdFactorsAdj,
        &mut P2gAffineAdj,
        &mut DeformationGradientAdj,
        &mut TrialDeformationAdj,
        &mut AffineVelocityAdj,
        &mut MaterialAdj,
        Option<&UpdateSaved>,
    )>,
) {
    let seen = seen.as_deref();
    let coef_dt = -params.dt_sub * 4.0 / (grid.dx * grid.dx);
    for (mat, body, svd, mut g_svd, mut g_a, mut g_f, mut g_ft, mut g_c, mut g_mat, saved) in
        &mut bodies
    {
        let k = coef_dt * body.particle_volume;
        let m = body.particle_mass;
        let n = svd.u.len();
        // What the recomputed forward saved of the material update, if it saved it.
        let saved = saved.map(|s| &s.0[..]);
        if let Some(sv) = saved {
            assert_eq!(sv.len(), n, "UpdateSaved sized for its body");
        }
        let g_svd = &mut *g_svd;
        // One partial sum of the material gradient per chunk of REDUCE_CHUNK particles, in
        // particle order, into a buffer kept between substeps.
        partial.clear();
        partial.resize(n.div_ceil(REDUCE_CHUNK), MaterialAdj::default());
        let r = REDUCE_CHUNK;
        partial
            .par_iter_mut()
            .zip(
                g_svd
                    .u
                    .par_chunks_mut(r)
                    .zip(g_svd.s.par_chunks_mut(r).zip(g_svd.v.par_chunks_mut(r))),
            )
            .zip(g_a.0.par_chunks_mut(r).zip(g_f.0.par_chunks_mut(r)))
            .zip(g_ft.0.par_chunks_mut(r).zip(g_c.0.par_chunks_mut(r)))
            .enumerate()
            .with_max_len(1)
            .for_each(|(ci, (((pm, (gu, (gs, gv))), (ga, gf)), (gft, gc)))| {
                for j in 0..gu.len() {
                    let i = ci * r + j;
                    let (u, s, v) = (svd.u[i], svd.s[i], svd.v[i]);
                    // A = m C + k U D Uᵀ
                    gc[j] += ga[j] * m;
                    let g_tau = ga[j] * k;
                    let g_d = diag_of(u.transpose() * g_tau * u);
                    // F' = U diag(σ') Vᵀ (the material ignores σ̄′ when F' = F_tmp).
                    let g_s_new = diag_of(u.transpose() * gf[j] * v);
                    // The material's adjoint also returns its forward update (σ′, τ_p).
                    let out = match saved {
                        Some(sv) => mat.update_adj_saved(s, 0.0, &sv[i], g_s_new, g_d),
                        None => mat.update_adj(s, 0.0, g_s_new, g_d),
                    };
                    let sym = g_tau + g_tau.transpose();
                    gu[j] += sym * compose(u, out.tau, DMat3::IDENTITY);
                    match out.sigma_new {
                        Some(sn) => {
                            gu[j] += gf[j] * compose(v, sn, DMat3::IDENTITY);
                            gv[j] += gf[j].transpose() * compose(u, sn, DMat3::IDENTITY);
                        }
                        None => gft[j] += gf[j],
                    }
                    gs[j] += out.g_sigma;
                    NonFiniteSeen::check(
                        seen,
                        gc[j].is_finite() && gs[j].is_finite() && gft[j].is_finite(),
                    );
                    *pm = *pm + out.g_material;
                    ga[j] = DMat3::ZERO;
                    gf[j] = DMat3::ZERO;
                }
            });
        *g_mat = partial.iter().fold(*g_mat, |a, b| a + *b);
    }
}
