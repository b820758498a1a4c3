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
use crate::math::lanes::{Arr, Vector};
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

/// Particles per group of [`outputs_lanes`].
const LANES: usize = 4;

/// A 3×3 matrix of `LANES` particles, `m[column][row]`, one particle to a lane.
type M3<V> = [[V; 3]; 3];

/// Column `j`, row `k` of the group's matrices, one particle to a lane.
// No closure here returns a vector (`docs/design.md` §11): the ones below give scalars.
#[inline(always)]
fn lanes_of<V: Vector<Scalar = f64>>(m: &[DMat3]) -> M3<V> {
    let mut out = [[V::splat(0.0); 3]; 3];
    for (j, col) in out.iter_mut().enumerate() {
        for (k, e) in col.iter_mut().enumerate() {
            *e = V::from_fn(|l| m[l].col(j)[k]);
        }
    }
    out
}

/// [`compose`] lane by lane, in glam's order: `a_j = u_j·d_j`, then column `j` of `a·wᵀ` is
/// `(a₀·w₀[j] + a₁·w₁[j]) + a₂·w₂[j]` (`DMat3::mul_vec3` on `wᵀ`'s column `j`).
#[inline(always)]
fn compose_lanes<V: Vector<Scalar = f64>>(u: &M3<V>, d: &[V; 3], w: &M3<V>) -> M3<V> {
    let mut a = *u;
    for (col, &d) in a.iter_mut().zip(d) {
        for e in col.iter_mut() {
            *e = *e * d;
        }
    }
    let mut out = a;
    for (j, col) in out.iter_mut().enumerate() {
        for (k, e) in col.iter_mut().enumerate() {
            *e = a[0][k] * w[0][j] + a[1][k] * w[1][j] + a[2][k] * w[2][j];
        }
    }
    out
}

/// What the stage writes for each particle of a chunk once its material has updated it: the
/// elastic `F′ = U·diag(σ′)·Vᵀ` (or `F_tmp` where the update keeps it) and the P2G affine term
/// [`p2g_affine`]. Groups of [`LANES`] go through [`compose_lanes`], each lane the scalar
/// functions' operations in their order, so the result is theirs to the bit
/// (`lanes_equal_the_scalar_outputs`); the tail goes one particle at a time.
struct Outputs<'a> {
    u: &'a [DMat3],
    v: &'a [DMat3],
    c: &'a [DMat3],
    ft: &'a [DMat3],
    updated: &'a [(Option<DVec3>, DVec3)],
    coef: f64,
    mass: f64,
    f_out: &'a mut [DMat3],
    a_out: &'a mut [DMat3],
}

impl Outputs<'_> {
    #[inline(always)]
    fn run<V: Vector<Scalar = f64>>(self) {
        let Outputs {
            u,
            v,
            c,
            ft,
            updated,
            coef,
            mass,
            f_out,
            a_out,
        } = self;
        let n = f_out.len();
        let groups = n - n % LANES;
        let (coef_v, mass_v) = (V::splat(coef), V::splat(mass));
        for g in (0..groups).step_by(LANES) {
            let r = g..g + LANES;
            let um: M3<V> = lanes_of(&u[r.clone()]);
            let vm: M3<V> = lanes_of(&v[r.clone()]);
            let cm: M3<V> = lanes_of(&c[r]);
            // A lane whose update keeps `F_tmp` composes zeros, which it then ignores.
            let up = &updated[g..g + LANES];
            let (mut s, mut tau) = ([V::splat(0.0); 3], [V::splat(0.0); 3]);
            for k in 0..3 {
                s[k] = V::from_fn(|l| up[l].0.map_or(0.0, |s| s[k]));
                tau[k] = V::from_fn(|l| up[l].1[k]);
            }
            let f = compose_lanes(&um, &s, &vm);
            let t = compose_lanes(&um, &tau, &um);
            let mut fs = [[[0.0; LANES]; 3]; 3];
            let mut aff = [[[0.0; LANES]; 3]; 3];
            for j in 0..3 {
                for k in 0..3 {
                    f[j][k].store(&mut fs[j][k]);
                    (t[j][k] * coef_v + cm[j][k] * mass_v).store(&mut aff[j][k]);
                }
            }
            for l in 0..LANES {
                let i = g + l;
                let mat = |m: &[[[f64; LANES]; 3]; 3]| {
                    DMat3::from_cols_array(&std::array::from_fn(|e| m[e / 3][e % 3][l]))
                };
                f_out[i] = if up[l].0.is_some() { mat(&fs) } else { ft[i] };
                a_out[i] = mat(&aff);
            }
        }
        for i in groups..n {
            let (s_new, tau_p) = updated[i];
            f_out[i] = match s_new {
                Some(s) => compose(u[i], s, v[i]),
                None => ft[i],
            };
            a_out[i] = p2g_affine(u[i], tau_p, c[i], coef, mass);
        }
    }
}

/// [`Outputs::run`] in AVX registers where the CPU has AVX2, in arrays elsewhere.
fn outputs(o: Outputs) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2, which is all the function's target features ask for.
        return unsafe { outputs_avx2(o) };
    }
    o.run::<Arr<f64, LANES>>()
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn outputs_avx2(o: Outputs) {
    o.run::<crate::math::lanes::F64x4>()
}

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
            if let Some(t) = tau_out.as_deref_mut() {
                for (t, &(_, tau_p)) in t.iter_mut().zip(&updated[..n]) {
                    *t = tau_p;
                }
            }
            let r = i0..i0 + n;
            outputs(Outputs {
                u: &svd.u[r.clone()],
                v: &svd.v[r.clone()],
                c: &c.0[r.clone()],
                ft: &ft.0[r],
                updated: &updated[..n],
                coef,
                mass,
                f_out: &mut *f_out,
                a_out: &mut *a_out,
            });
            for (f, a) in f_out.iter().zip(a_out.iter()) {
                watch.check(f.is_finite() && a.is_finite());
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
                health.report(Fault {
                    stage: "constitutive",
                    field,
                    owner: format!("body '{}' particle", body.name),
                    index: i,
                    value: format!("{value:?}"),
                });
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every lane of the portable arrays and of the AVX registers is the scalar [`compose`] and
    /// [`p2g_affine`] to the bit, for updates that project (`Some`) and keep `F_tmp` (`None`)
    /// side by side in a group, with signed zeros, a subnormal, a large and a non-finite entry,
    /// and chunk lengths with a tail of 0 to 3.
    #[test]
    fn lanes_equal_the_scalar_outputs() {
        let mut seed = 3u64;
        let mut u = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let count = 23;
        let mut mats = |special: bool| -> Vec<DMat3> {
            (0..count)
                .map(|i| {
                    let mut m = std::array::from_fn(|_| u());
                    if special {
                        m[i % 9] = [-0.0, 1e-310, 3e200, f64::INFINITY][i % 4];
                    }
                    DMat3::from_cols_array(&m)
                })
                .collect()
        };
        let (us, vs, cs, fts) = (mats(true), mats(false), mats(true), mats(false));
        let updated: Vec<(Option<DVec3>, DVec3)> = (0..count)
            .map(|i| {
                let s = DVec3::new(1.0 + u(), 1.0 + u(), 1.0 + u());
                let tau = DVec3::new(u(), -0.0, 1e4 * u());
                ((i % 3 != 1).then_some(s), tau)
            })
            .collect();
        let (coef, mass) = (-3.7e-3, 0.021);
        let bits = |m: &[DMat3]| -> Vec<u64> {
            m.iter()
                .flat_map(|m| m.to_cols_array())
                .map(f64::to_bits)
                .collect()
        };
        for n in [20, 21, 22, 23] {
            let want_f: Vec<DMat3> = (0..n)
                .map(|i| match updated[i].0 {
                    Some(s) => compose(us[i], s, vs[i]),
                    None => fts[i],
                })
                .collect();
            let want_a: Vec<DMat3> = (0..n)
                .map(|i| p2g_affine(us[i], updated[i].1, cs[i], coef, mass))
                .collect();
            for dispatched in [false, true] {
                let (mut f, mut a) = (vec![DMat3::ZERO; n], vec![DMat3::ZERO; n]);
                let o = Outputs {
                    u: &us[..n],
                    v: &vs[..n],
                    c: &cs[..n],
                    ft: &fts[..n],
                    updated: &updated[..n],
                    coef,
                    mass,
                    f_out: &mut f,
                    a_out: &mut a,
                };
                if dispatched {
                    outputs(o)
                } else {
                    o.run::<Arr<f64, LANES>>()
                }
                assert_eq!(
                    bits(&f),
                    bits(&want_f),
                    "F, n = {n}, dispatched {dispatched}"
                );
                assert_eq!(
                    bits(&a),
                    bits(&want_a),
                    "A, n = {n}, dispatched {dispatched}"
                );
            }
        }
    }
}
