//! The flow law of the collapse cases' powder ([`super::collapse_scene`],
//! [`super::axisym::axisym_scene`]): Klár's cone, the published cases' law, or μ(I) with the
//! cone's static friction, which `collapse_convergence` compares with it.

/// The flow law of a collapse's powder (bulk density 1500 kg/m³, ν = 0.3).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Rheology {
    /// Klár's Drucker–Prager cone at the case's friction angle (cohesive where the case has a
    /// cohesion).
    DruckerPrager,
    /// The μ(I) rheology (`materials::mu_i`), grains of 2450 kg/m³.
    MuI {
        mu_s: f64,
        mu_2: f64,
        i_0: f64,
        /// Grain diameter (m).
        grain_diameter: f64,
    },
}

impl Rheology {
    /// μ(I) whose static friction is the Drucker–Prager cone's at Klár's `friction_deg` as
    /// this model's return measures it (`μ = 3α/√2`, the plane-strain `sin φ_eff` of
    /// `shared/validation/granular.md`), with Jop et al.'s glass beads' rise `μ₂ − μ_s` and
    /// `I₀` and grains of `grain_diameter`: the same powder at rest, with a rate-dependent
    /// flow.
    pub fn mu_i_matching(friction_deg: f64, grain_diameter: f64) -> Rheology {
        let mu_s = 3.0 * crate::math::return_map::dp_alpha(friction_deg) / std::f64::consts::SQRT_2;
        let rise = 32.76f64.to_radians().tan() - 20.9f64.to_radians().tan();
        Rheology::MuI {
            mu_s,
            mu_2: mu_s + rise,
            i_0: 0.279,
            grain_diameter,
        }
    }

    /// The scene's material at Young's modulus `e` (Pa).
    pub fn material(&self, e: f64, friction_deg: f64, cohesion: f64) -> String {
        match *self {
            Rheology::DruckerPrager if cohesion > 0.0 => format!(
                "CohesiveDruckerPrager((density: 1500.0, youngs_modulus: {e}, poisson_ratio: 0.3,
                                         friction_deg: {friction_deg}, cohesion: {cohesion}))"
            ),
            Rheology::DruckerPrager => format!(
                "DruckerPrager((density: 1500.0, youngs_modulus: {e}, poisson_ratio: 0.3,
                                         friction_deg: {friction_deg}))"
            ),
            Rheology::MuI {
                mu_s,
                mu_2,
                i_0,
                grain_diameter,
            } => format!(
                "MuI((density: 1500.0, youngs_modulus: {e}, poisson_ratio: 0.3, mu_s: {mu_s},
                      mu_2: {mu_2}, i_0: {i_0}, grain_diameter: {grain_diameter},
                      grain_density: 2450.0))"
            ),
        }
    }
}
