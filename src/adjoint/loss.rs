//! Losses on the final particle positions, each with its gradient `∂L/∂x` (the seed of the
//! backward pass).
//!
//! - [`Loss::SumDistance`], seed paper eq. 5: `L = Σ_p ‖x_p − t‖`, with `t` the bottom centre of
//!   the target cup. It pulls every particle towards the target, so its gradient never vanishes;
//!   it is the default loss of the transport task.
//! - [`Loss::Dosing`], for a weighing lab that wants a target mass `m*` in the target cup:
//!   `L = ((M − m*)/m*)²` with the *soft* mass `M = Σ_p m_p·s(x_p)` (see [`CupRegion::soft`]).
//!   The hard count (is the particle inside the cavity?) is piecewise constant, so its gradient
//!   is zero almost everywhere; the soft indicator replaces each step of the indicator by a
//!   logistic ramp of width `w`, which makes `M` smooth, tends to the hard mass as `w → 0`, and
//!   gives a gradient to the particles within a few `w` of the cavity's boundary. Far from the
//!   cup (many `w` away) the gradient vanishes like `e^(−d/w)`: start dosing from a skill that
//!   already reaches the cup (for example one optimised with eq. 5), or use a wider `w`.
//! - [`Loss::HeightField`] and [`Loss::Chamfer`], for calibration from observations: the mean
//!   squared gap between the observed surface heights and the particles' soft heights
//!   ([`crate::math::heightfield`]), and the Chamfer distance to an observed point cloud
//!   ([`crate::math::chamfer`]). Both are smooth sums over many particles.
//! - [`Loss::MeanL1`], the Taichi reference benchmark's loss, and [`Loss::Linear`], for
//!   closed-form checks.
//!
//! `|·|` and `‖·‖` use the subgradient 0 at 0.

use glam::DVec3;

use crate::math::chamfer;
use crate::math::geometry::logistic;
pub use crate::math::geometry::CupRegion;
use crate::math::heightfield::{self, HeightGrid};
pub use crate::math::region::PlateRegion;
use crate::scene::{LossSpec, Scene};

/// The dosing loss's default ramp width, in particle spacings. With the soft region's faces in
/// the middle of the cup's wall and floor ([`CupRegion::soft`]), a grain resting inside is at
/// least `t/2 + h/2` from a face (`t` the solid's thickness, `h` the spacing): 2.25 mm for the
/// shipped cups at `h` = 2.5 mm, nine widths at `h/4`, where the logistic is 0.9999. At `h/2` the
/// settled doses' soft mass was up to 1.3 % short, at `h/4` within 0.007 g of the hard count
/// (`tests/dosing_soft_mass_counts_settled_grains.rs`).
pub const DOSING_WIDTH_PER_SPACING: f64 = 0.25;

/// The dosing loss's settings.
#[derive(Clone, Debug, PartialEq)]
pub struct Dosing {
    pub cup: CupRegion,
    /// Mass of one particle of each body (kg), in scene order.
    pub particle_mass: Vec<f64>,
    /// Target mass `m*` (kg), > 0.
    pub target_mass: f64,
    /// Width `w` of the soft indicator's ramps (m), > 0.
    pub width: f64,
}

impl Dosing {
    /// The soft transported mass `M = Σ_p m_p·s(x_p)` (kg).
    pub fn soft_mass(&self, xs: &[Vec<DVec3>]) -> f64 {
        xs.iter()
            .zip(&self.particle_mass)
            .map(|(x, &m)| {
                x.iter()
                    .map(|p| m * self.cup.soft(*p, self.width).0)
                    .sum::<f64>()
            })
            .sum()
    }
}

/// A loss on the final particle positions.
#[derive(Clone, Debug)]
pub enum Loss {
    /// `mean_p Σ_d |x_p,d − t_d|`, the Taichi reference benchmark's loss.
    MeanL1(DVec3),
    /// `Σ_p ‖x_p − t‖` (seed paper eq. 5).
    SumDistance(DVec3),
    /// `Σ_bodies Σ_p w_p·x_p` with given weights (closed-form checks).
    Linear(Vec<Vec<DVec3>>),
    /// `((M − m*)/m*)²` with the soft transported mass `M` (see the module docs).
    Dosing(Dosing),
    /// `(1/n) Σ_c (h_c − o_c)²` between the soft surface heights and an observed height map.
    HeightField(HeightObservation),
    /// The Chamfer distance between all bodies' particles and an observed point cloud.
    Chamfer(chamfer::ObservedCloud),
    /// `inner` on the particles of some bodies only (indices in scene order): an observation of
    /// one body, such as a coloured layer segmented in a camera image. The other bodies'
    /// particles get no gradient.
    Only {
        bodies: Vec<usize>,
        inner: Box<Loss>,
    },
    /// The push loss: the mean over grains of the softplus distance still to go into a plate's
    /// region, with ramps of `width` (m) ([`PlateRegion::distance`]).
    Region { region: PlateRegion, width: f64 },
}

/// An observed height map and the soft height's settings ([`crate::math::heightfield`]).
#[derive(Clone, Debug, PartialEq)]
pub struct HeightObservation {
    pub grid: HeightGrid,
    /// Observed height per pixel (m), NaN where unseen; `grid.len()` entries.
    pub observed: Vec<f64>,
    /// How the simulated heights are made soft: the floor an empty pixel reads, a grain's half
    /// height, the temperature and the footprint's edge.
    pub soft: heightfield::SoftHeight,
}

impl HeightObservation {
    /// The simulated soft heights of `xs`.
    pub fn heights(&self, xs: &[DVec3]) -> Vec<f64> {
        heightfield::soft_heights(&self.grid, xs, &self.soft)
    }
}

/// Every body's positions in one slice, and the gradient split back per body.
fn on_all_bodies(
    xs: &[Vec<DVec3>],
    f: impl FnOnce(&[DVec3]) -> (f64, Vec<DVec3>),
) -> (f64, Vec<Vec<DVec3>>) {
    let all: Vec<DVec3> = xs.iter().flatten().copied().collect();
    let (l, g) = f(&all);
    let mut rest = g.as_slice();
    let split = xs
        .iter()
        .map(|x| {
            let (a, b) = rest.split_at(x.len());
            rest = b;
            a.to_vec()
        })
        .collect();
    (l, split)
}

fn sign(v: f64) -> f64 {
    if v > 0.0 {
        1.0
    } else if v < 0.0 {
        -1.0
    } else {
        0.0
    }
}

impl Loss {
    /// The loss and `∂L/∂x` per body.
    pub fn eval(&self, xs: &[Vec<DVec3>]) -> (f64, Vec<Vec<DVec3>>) {
        match self {
            Loss::Only { bodies, inner } => {
                let some: Vec<Vec<DVec3>> = bodies.iter().map(|&b| xs[b].clone()).collect();
                let (l, g_some) = inner.eval(&some);
                let mut g: Vec<Vec<DVec3>> =
                    xs.iter().map(|x| vec![DVec3::ZERO; x.len()]).collect();
                for (&b, gb) in bodies.iter().zip(g_some) {
                    g[b] = gb;
                }
                return (l, g);
            }
            Loss::HeightField(o) => {
                return on_all_bodies(xs, |all| {
                    let (l, g_h) = heightfield::squared_error(&o.heights(all), &o.observed);
                    let g = heightfield::soft_heights_adj(&o.grid, all, &o.soft, &g_h);
                    (l, g)
                })
            }
            Loss::Chamfer(o) => return on_all_bodies(xs, |all| chamfer::chamfer(all, o)),
            Loss::Region { region, width } => return region.push_loss(xs, *width),
            _ => {}
        }
        if let Loss::Dosing(d) = self {
            let mass = d.soft_mass(xs);
            let r = (mass - d.target_mass) / d.target_mass;
            // ∂L/∂M = 2r/m*, ∂M/∂x_p = m_p·∇s(x_p).
            let g_mass = 2.0 * r / d.target_mass;
            let g = xs
                .iter()
                .zip(&d.particle_mass)
                .map(|(x, &m)| {
                    x.iter()
                        .map(|p| d.cup.soft(*p, d.width).1 * (g_mass * m))
                        .collect()
                })
                .collect();
            return (r * r, g);
        }
        let n: usize = xs.iter().map(|x| x.len()).sum();
        let mut l = 0.0;
        let g = xs
            .iter()
            .enumerate()
            .map(|(b, x)| {
                x.iter()
                    .enumerate()
                    .map(|(i, p)| match self {
                        Loss::MeanL1(t) => {
                            let d = *p - *t;
                            l += (d.x.abs() + d.y.abs() + d.z.abs()) / n as f64;
                            DVec3::new(sign(d.x), sign(d.y), sign(d.z)) / n as f64
                        }
                        Loss::SumDistance(t) => {
                            let d = *p - *t;
                            let len = d.length();
                            l += len;
                            if len > 0.0 {
                                d / len
                            } else {
                                DVec3::ZERO
                            }
                        }
                        Loss::Linear(w) => {
                            l += w[b][i].dot(*p);
                            w[b][i]
                        }
                        Loss::Dosing(_)
                        | Loss::HeightField(_)
                        | Loss::Chamfer(_)
                        | Loss::Region { .. }
                        | Loss::Only { .. } => {
                            unreachable!("handled above")
                        }
                    })
                    .collect()
            })
            .collect();
        (l, g)
    }
}

/// The loss a scene declares, or its default (see [`crate::scene::Scene::loss`]).
pub fn scene_loss(scene: &Scene) -> Loss {
    match scene.loss {
        Some(LossSpec::MeanL1(t)) => Loss::MeanL1(DVec3::from(t)),
        Some(LossSpec::SumDistance(t)) => Loss::SumDistance(DVec3::from(t)),
        Some(LossSpec::Dosing { grams, width }) => Loss::Dosing(Dosing {
            cup: scene
                .target_region()
                .expect("validated: a dosing loss has a task with a target cup"),
            particle_mass: scene.particle_masses(),
            target_mass: grams * 1e-3,
            width: width.unwrap_or_else(|| {
                DOSING_WIDTH_PER_SPACING
                    * scene
                        .bodies
                        .iter()
                        .map(|b| scene.particle_spacing(b))
                        .fold(scene.simulation.dx, f64::min)
            }),
        }),
        None => Loss::SumDistance(loss_target(scene)),
    }
}

/// The default loss target of a scene: the middle of the target cup's floor, else the middle of
/// the domain's floor.
pub fn loss_target(scene: &Scene) -> DVec3 {
    if let Some(cup) = scene.target_region() {
        return cup.pose.to_world(DVec3::new(0.0, cup.floor, 0.0));
    }
    let (lo, hi) = scene.domain();
    DVec3::new(0.5 * (lo.x + hi.x), lo.y, 0.5 * (lo.z + hi.z))
}

/// A loss on what a tool carries at one step: `w·((C − c*)/c*)²` with the soft carried mass
/// `C = Σ_p m_p·σ((r − ‖q_p − c‖)/ε)`, `q_p = Rᵀ(x_p − t)` the particle in the tool's frame,
/// and a ball of radius `r` about `c` in that frame (for a spoon, the bowl's sphere, `c = 0`:
/// its cavity and a heap up to a radius above the rim). Eq. 5 and the dosing loss see where grains end;
/// this sees how many the tool holds while it moves, which is what the scoop parameters set.
///
/// Its gradient reaches the particles and, because the ball moves with the tool, the tool's
/// pose: with rotations as world-frame perturbations `δR = [δθ]×·R` (the convention of the
/// tool-move adjoint), `∂C/∂t = −Σ ∂C/∂x_p` and `∂C/∂θ = Σ ∂C/∂x_p × (x_p − t)`.
#[derive(Clone, Debug, PartialEq)]
pub struct Carry {
    /// The tool's collider name.
    pub tool: String,
    /// The global step whose start state is scored (`steps` for the final state).
    pub step: usize,
    /// Centre `c` of the ball in the tool's frame (m).
    pub centre: DVec3,
    /// Radius `r` of the ball (m).
    pub radius: f64,
    /// Width `ε` of the logistic ramp (m), > 0.
    pub width: f64,
    /// Mass of one particle of each body (kg), in scene order.
    pub particle_mass: Vec<f64>,
    /// Target carried mass `c*` (kg), > 0.
    pub target_mass: f64,
    /// Weight `w` of the term.
    pub weight: f64,
}

/// A loss on the state at the start of a global step, added to a backward pass's loss on the
/// final state ([`crate::adjoint::tape::gradient_with`]).
#[derive(Clone, Debug)]
pub enum Term {
    /// What a tool carries at its step.
    Carry(Carry),
    /// A loss on every body's positions at `step`: an observation of the state at that time (a
    /// height map or point cloud of a sequence).
    Positions { step: usize, loss: Loss },
}

impl Term {
    /// The global step whose start state it scores (`steps` for the final state).
    pub fn step(&self) -> usize {
        match self {
            Term::Carry(c) => c.step,
            Term::Positions { step, .. } => *step,
        }
    }
}

/// A [`Carry`] term's value and gradients.
#[derive(Clone, Debug, PartialEq)]
pub struct CarryGrad {
    pub value: f64,
    /// The soft carried mass `C` (kg).
    pub mass: f64,
    pub x: Vec<Vec<DVec3>>,
    /// `∂/∂t` of the tool's translation.
    pub translation: DVec3,
    /// `∂/∂θ`, a world-frame rotation perturbation of the tool.
    pub rotation: DVec3,
}

/// The soft ball indicator `σ((r − ‖q‖)/ε)` of a world point `x`, `q = Rᵀ(x − t) − c`, and its
/// world gradient `∂/∂x`.
pub fn soft_ball(
    x: DVec3,
    pose: &crate::math::pose::Pose,
    centre: DVec3,
    radius: f64,
    width: f64,
) -> (f64, DVec3) {
    let q = pose.to_local(x) - centre;
    let d = q.length();
    let s = logistic((radius - d) / width);
    if d == 0.0 {
        return (s, DVec3::ZERO);
    }
    // ∂s/∂q = −σ'(z)/ε · q/‖q‖, and ∂q/∂x = Rᵀ, so ∂s/∂x = R·∂s/∂q.
    let g_local = q * (-s * (1.0 - s) / (width * d));
    (s, pose.rotation * g_local)
}

impl Carry {
    /// The value and gradients at positions `xs` (per body) with the tool at `pose`.
    pub fn eval(&self, xs: &[Vec<DVec3>], pose: &crate::math::pose::Pose) -> CarryGrad {
        let mut mass = 0.0;
        let per: Vec<Vec<(f64, DVec3)>> = xs
            .iter()
            .zip(&self.particle_mass)
            .map(|(x, &m)| {
                x.iter()
                    .map(|p| {
                        let (s, g) = soft_ball(*p, pose, self.centre, self.radius, self.width);
                        mass += m * s;
                        (s, g * m)
                    })
                    .collect()
            })
            .collect();
        let r = (mass - self.target_mass) / self.target_mass;
        let g_mass = self.weight * 2.0 * r / self.target_mass;
        let mut translation = DVec3::ZERO;
        let mut rotation = DVec3::ZERO;
        let x: Vec<Vec<DVec3>> = per
            .iter()
            .zip(xs)
            .map(|(b, xb)| {
                b.iter()
                    .zip(xb)
                    .map(|(&(_, g), p)| {
                        let gx = g * g_mass;
                        translation -= gx;
                        rotation += gx.cross(*p - pose.translation);
                        gx
                    })
                    .collect()
            })
            .collect();
        CarryGrad {
            value: self.weight * r * r,
            mass,
            x,
            translation,
            rotation,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::pose::Pose;
    use glam::DQuat;

    /// Central differences in f64 of smooth functions of O(1) size.
    const FD_EPS: f64 = 1e-6;
    const REL_TOL: f64 = 1e-6;

    fn cup() -> CupRegion {
        CupRegion {
            pose: Pose {
                translation: DVec3::new(0.18, 0.0075, 0.05),
                rotation: DQuat::from_rotation_z(0.3),
            },
            inner_radius: 0.028,
            floor: 0.003,
            rim: 0.05,
            wall: 0.002,
        }
    }

    fn points() -> Vec<Vec<DVec3>> {
        let c = cup().pose;
        vec![
            [
                // Off the axis, where ρ = |(x, z)| has its kink.
                (0.001, 0.01, 0.0005),
                (0.027, 0.02, 0.001),
                (0.01, 0.049, -0.012),
                // Outside the wall, just above the floor's height.
                (0.025, 0.0035, 0.02),
            ]
            .iter()
            .map(|&(x, y, z)| c.to_world(DVec3::new(x, y, z)))
            .collect(),
            vec![c.to_world(DVec3::new(-0.0315, 0.03, 0.0))],
        ]
    }

    /// Away from the solid (where grains are), the soft indicator tends to the hard one.
    #[test]
    fn soft_indicator_tends_to_the_hard_one() {
        let c = cup();
        for p in points().iter().flatten() {
            let (s, _) = c.soft(*p, 1e-6);
            let hard = if c.inside(*p) { 1.0 } else { 0.0 };
            assert!((s - hard).abs() < 1e-6, "{p}: soft {s} hard {hard}");
        }
    }

    #[test]
    fn dosing_gradient_matches_central_differences() {
        let loss = Loss::Dosing(Dosing {
            cup: cup(),
            particle_mass: vec![2.3e-5, 4.0e-5],
            target_mass: 5e-5,
            width: 0.002,
        });
        let xs = points();
        let (_, g) = loss.eval(&xs);
        for b in 0..xs.len() {
            for i in 0..xs[b].len() {
                for a in 0..3 {
                    let mut p = xs.clone();
                    let mut m = xs.clone();
                    // A step of w/2000: the ramps are smooth on the scale of w = 2 mm, and a
                    // shorter step loses the small components (10⁻⁵) to rounding.
                    p[b][i][a] += FD_EPS;
                    m[b][i][a] -= FD_EPS;
                    let fd = (loss.eval(&p).0 - loss.eval(&m).0) / (2.0 * FD_EPS);
                    let ad = g[b][i][a];
                    assert!(
                        (fd - ad).abs() <= REL_TOL * fd.abs().max(ad.abs()).max(1e-3),
                        "body {b} particle {i} axis {a}: fd {fd} adjoint {ad}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_loss_on_some_bodies_sees_only_theirs_and_pulls_only_theirs() {
        let t = DVec3::new(0.1, 0.0, 0.2);
        let xs = vec![
            vec![DVec3::new(0.1, 0.3, 0.6)],
            vec![DVec3::new(0.4, 0.0, 0.2), DVec3::new(0.1, 0.0, 0.5)],
            vec![DVec3::new(0.1, 0.7, 0.2)],
        ];
        let only = Loss::Only {
            bodies: vec![2, 1],
            inner: Box::new(Loss::SumDistance(t)),
        };
        let (l, g) = only.eval(&xs);
        // Bodies 2 and 1: 0.7 + 0.3 + 0.3.
        assert!((l - 1.3).abs() < 1e-15, "{l}");
        assert_eq!(g[0], vec![DVec3::ZERO]);
        let (_, g1) = Loss::SumDistance(t).eval(&xs[1..2]);
        assert_eq!(g[1], g1[0]);
        assert!((g[2][0] - DVec3::Y).length() < 1e-15);
    }

    #[test]
    fn sum_distance_gradient_is_the_unit_direction() {
        let t = DVec3::new(0.1, 0.0, 0.2);
        let xs = vec![vec![DVec3::new(0.1, 0.3, 0.6), t]];
        let (l, g) = Loss::SumDistance(t).eval(&xs);
        assert!((l - 0.5).abs() < 1e-15);
        assert!((g[0][0] - DVec3::new(0.0, 0.6, 0.8)).length() < 1e-15);
        assert_eq!(g[0][1], DVec3::ZERO);
    }

    #[test]
    fn carry_gradient_matches_central_differences_in_the_particles_and_the_pose() {
        use crate::math::pose::quat_from_rotation_vector;
        let pose = Pose {
            translation: DVec3::new(0.06, 0.07, 0.05),
            rotation: DQuat::from_euler(glam::EulerRot::XYZ, 0.3, -1.2, 0.4),
        };
        let xs: Vec<Vec<DVec3>> = vec![
            [
                (0.004, 0.003, -0.002),
                (0.011, -0.009, 0.004),
                (-0.013, 0.002, 0.006),
            ]
            .iter()
            .map(|&(a, b, c)| pose.to_world(DVec3::new(a, b, c)))
            .collect(),
            vec![pose.to_world(DVec3::new(0.0, 0.0145, 0.003))],
        ];
        let carry = Carry {
            tool: "spoon".into(),
            step: 0,
            // Off the frame's origin, so that turning the tool moves the ball.
            centre: DVec3::new(0.002, 0.006, -0.001),
            radius: 0.015,
            width: 0.003,
            particle_mass: vec![2.3e-5, 4.0e-5],
            target_mass: 5e-5,
            weight: 1.7,
        };
        let g = carry.eval(&xs, &pose);
        assert!(g.mass > 0.0 && g.value > 0.0);
        let check = |fd: f64, ad: f64, what: &str| {
            assert!(
                (fd - ad).abs() <= REL_TOL * fd.abs().max(ad.abs()).max(1e-3),
                "{what}: fd {fd} adjoint {ad}"
            );
        };
        let h = FD_EPS * 1e-2;
        for b in 0..xs.len() {
            for i in 0..xs[b].len() {
                for a in 0..3 {
                    let (mut p, mut m) = (xs.clone(), xs.clone());
                    p[b][i][a] += h;
                    m[b][i][a] -= h;
                    let fd =
                        (carry.eval(&p, &pose).value - carry.eval(&m, &pose).value) / (2.0 * h);
                    check(fd, g.x[b][i][a], &format!("x[{b}][{i}][{a}]"));
                }
            }
        }
        for a in 0..3 {
            let mut e = DVec3::ZERO;
            e[a] = h;
            let moved = |d: DVec3| Pose {
                translation: pose.translation + d,
                ..pose
            };
            let fd =
                (carry.eval(&xs, &moved(e)).value - carry.eval(&xs, &moved(-e)).value) / (2.0 * h);
            check(fd, g.translation[a], &format!("t[{a}]"));
            // δR = [δθ]×·R: a world-frame rotation applied after R.
            let turned = |d: DVec3| Pose {
                rotation: quat_from_rotation_vector(d) * pose.rotation,
                ..pose
            };
            let fd = (carry.eval(&xs, &turned(e)).value - carry.eval(&xs, &turned(-e)).value)
                / (2.0 * h);
            check(fd, g.rotation[a], &format!("theta[{a}]"));
        }
    }
}
