//! Every adjoint system, run alone on a small random state, agrees with central differences of
//! its forward system: for a random output weighting `W` and a random input direction `δ`,
//! `Σ ∂L/∂input·δ` from the adjoint equals `(L(in + εδ) − L(in − εδ))/2ε`, `L = W·output`.

use bevy_ecs::prelude::*;
use bevy_ecs::system::RunSystemOnce;
use glam::{DMat3, DVec3};
use powderlab::adjoint;
use powderlab::adjoint::gravity::GravityAdj;
use powderlab::adjoint::grid_collision::WallInputVelocity;
use powderlab::adjoint::NonFiniteSeen;
use powderlab::components::*;
use powderlab::materials::drucker_prager::DruckerPrager;
use powderlab::materials::Material;
use powderlab::systems;

/// f64 central differences with ε = 1e-6 resolve these smooth maps to ~1e-9; the adjoint must
/// agree to 1e-6 relative.
const FD_EPS: f64 = 1e-6;
const REL_TOL: f64 = 1e-6;
const N: usize = 40;
const NG: usize = 12;

struct Rng(powderlab::util::Lcg);
impl Rng {
    fn new(seed: u64) -> Self {
        Self(powderlab::util::Lcg(seed))
    }
    fn f(&mut self) -> f64 {
        self.0.symmetric()
    }
    fn v(&mut self) -> DVec3 {
        DVec3::new(self.f(), self.f(), self.f())
    }
    fn m(&mut self) -> DMat3 {
        DMat3::from_cols(self.v(), self.v(), self.v())
    }
    fn vs(&mut self, n: usize) -> Vec<DVec3> {
        (0..n).map(|_| self.v()).collect()
    }
    fn ms(&mut self, n: usize) -> Vec<DMat3> {
        (0..n).map(|_| self.m()).collect()
    }
}

fn dotv(a: &[DVec3], b: &[DVec3]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x.dot(*y)).sum()
}
fn dotm(a: &[DMat3], b: &[DMat3]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| {
            x.to_cols_array()
                .iter()
                .zip(y.to_cols_array())
                .map(|(p, q)| p * q)
                .sum::<f64>()
        })
        .sum()
}
fn axpy_v(a: &[DVec3], s: f64, d: &[DVec3]) -> Vec<DVec3> {
    a.iter().zip(d).map(|(x, y)| *x + *y * s).collect()
}
fn axpy_m(a: &[DMat3], s: f64, d: &[DMat3]) -> Vec<DMat3> {
    a.iter().zip(d).map(|(x, y)| *x + *y * s).collect()
}

fn check(what: &str, fd: f64, ad: f64) {
    let rel = (fd - ad).abs() / fd.abs().max(ad.abs()).max(1e-12);
    println!("{what}: adjoint {ad:.10e} fd {fd:.10e} rel {rel:.1e}");
    assert!(rel <= REL_TOL, "{what}: adjoint {ad} vs fd {fd} ({rel})");
}

/// A world with one body of `N` random particles inside a 12³ grid and zeroed adjoints.
fn world(rng: &mut Rng) -> (World, Entity) {
    let mut w = World::new();
    let dx = 0.01;
    w.insert_resource(Grid::new(DVec3::ZERO, dx, [NG, NG, NG]));
    w.insert_resource(SimParams {
        dt: 0.01,
        substeps: 10,
        dt_sub: 1e-3,
        gravity: DVec3::new(0.0, -9.81, 0.0),
        empty_node_mass: 0.0,
        svd: Precision::F64,
    });
    w.insert_resource(Health::default());
    w.insert_resource(Clock::default());
    w.insert_resource(GridAdj::new(NG * NG * NG));
    w.insert_resource(GravityAdj::default());
    w.insert_resource(NonFiniteSeen::default());
    w.insert_resource(DomainWalls {
        cells: 3,
        mode: ContactMode::Separate,
        friction: 0.3,
    });
    w.insert_resource(WallInputVelocity(vec![DVec3::ZERO; NG * NG * NG]));
    let x: Vec<DVec3> = (0..N)
        .map(|_| DVec3::splat(0.06) + rng.v() * 0.03)
        .collect();
    let f: Vec<DMat3> = (0..N).map(|_| DMat3::IDENTITY + rng.m() * 0.05).collect();
    let e = w
        .spawn((
            Body {
                name: "b".into(),
                index: 0,
                particle_mass: 1.5e-3,
                particle_volume: 1e-6,
                lame: (0.0, 0.0),
            },
            Position(x.clone()),
            Velocity(rng.vs(N)),
            AffineVelocity(rng.ms(N)),
            DeformationGradient(f.clone()),
            TrialDeformation(f),
            SvdFactors {
                u: vec![DMat3::IDENTITY; N],
                s: vec![DVec3::ONE; N],
                v: vec![DMat3::IDENTITY; N],
            },
            P2gAffine(rng.ms(N)),
            ScatterOrder::default(),
            DruckerPrager::new(1e5, 0.3, 30.0).prepared(),
        ))
        .id();
    w.entity_mut(e).insert((
        PositionAdj(vec![DVec3::ZERO; N]),
        VelocityAdj(vec![DVec3::ZERO; N]),
        AffineVelocityAdj(vec![DMat3::ZERO; N]),
        DeformationGradientAdj(vec![DMat3::ZERO; N]),
        TrialDeformationAdj(vec![DMat3::ZERO; N]),
        SvdFactorsAdj {
            u: vec![DMat3::ZERO; N],
            s: vec![DVec3::ZERO; N],
            v: vec![DMat3::ZERO; N],
        },
        P2gAffineAdj(vec![DMat3::ZERO; N]),
        SubstepStart::default(),
        MaterialAdj::default(),
    ));
    (w, e)
}

#[test]
fn deformation_update() {
    let mut rng = Rng::new(1);
    let (mut w, e) = world(&mut rng);
    let (c0, f0) = (
        w.get::<AffineVelocity>(e).unwrap().0.clone(),
        w.get::<DeformationGradient>(e).unwrap().0.clone(),
    );
    let (wt, dc, df) = (rng.ms(N), rng.ms(N), rng.ms(N));
    let loss = |w: &mut World, c: &[DMat3], f: &[DMat3]| {
        w.get_mut::<AffineVelocity>(e).unwrap().0 = c.to_vec();
        w.get_mut::<DeformationGradient>(e).unwrap().0 = f.to_vec();
        w.run_system_once(systems::deformation_update::deformation_update)
            .unwrap();
        dotm(&w.get::<TrialDeformation>(e).unwrap().0, &wt)
    };
    let fd = (loss(&mut w, &axpy_m(&c0, FD_EPS, &dc), &axpy_m(&f0, FD_EPS, &df))
        - loss(
            &mut w,
            &axpy_m(&c0, -FD_EPS, &dc),
            &axpy_m(&f0, -FD_EPS, &df),
        ))
        / (2.0 * FD_EPS);
    w.get_mut::<SubstepStart>(e).unwrap().c = c0;
    w.get_mut::<SubstepStart>(e).unwrap().f = f0;
    w.get_mut::<TrialDeformationAdj>(e).unwrap().0 = wt;
    w.run_system_once(adjoint::deformation_update::deformation_update_adjoint)
        .unwrap();
    let ad = dotm(&w.get::<AffineVelocityAdj>(e).unwrap().0, &dc)
        + dotm(&w.get::<DeformationGradientAdj>(e).unwrap().0, &df);
    check("deformation_update", fd, ad);
}

#[test]
fn svd() {
    let mut rng = Rng::new(2);
    let (mut w, e) = world(&mut rng);
    let ft0 = w.get::<TrialDeformation>(e).unwrap().0.clone();
    let (wu, ws, wv, d) = (rng.ms(N), rng.vs(N), rng.ms(N), rng.ms(N));
    let loss = |w: &mut World, ft: &[DMat3]| {
        w.get_mut::<TrialDeformation>(e).unwrap().0 = ft.to_vec();
        // Cold start each time: the decomposition must not depend on the warm start.
        let mut s = w.get_mut::<SvdFactors>(e).unwrap();
        s.v = vec![DMat3::IDENTITY; N];
        w.run_system_once(systems::svd::svd).unwrap();
        let s = w.get::<SvdFactors>(e).unwrap();
        dotm(&s.u, &wu) + dotv(&s.s, &ws) + dotm(&s.v, &wv)
    };
    let fd = (loss(&mut w, &axpy_m(&ft0, FD_EPS, &d)) - loss(&mut w, &axpy_m(&ft0, -FD_EPS, &d)))
        / (2.0 * FD_EPS);
    loss(&mut w, &ft0);
    let mut g = w.get_mut::<SvdFactorsAdj>(e).unwrap();
    (g.u, g.s, g.v) = (wu, ws, wv);
    w.run_system_once(adjoint::svd::svd_adjoint).unwrap();
    check(
        "svd",
        fd,
        dotm(&w.get::<TrialDeformationAdj>(e).unwrap().0, &d),
    );
}

#[test]
fn constitutive_drucker_prager() {
    let mut rng = Rng::new(3);
    let (mut w, e) = world(&mut rng);
    w.run_system_once(systems::svd::svd).unwrap();
    let s0 = w.get::<SvdFactors>(e).unwrap().clone();
    let c0 = w.get::<AffineVelocity>(e).unwrap().0.clone();
    let (wf, wa) = (rng.ms(N), rng.ms(N));
    let (du, ds, dv, dc) = (rng.ms(N), rng.vs(N), rng.ms(N), rng.ms(N));
    let ds: Vec<DVec3> = ds.iter().map(|d| *d * 0.01).collect();
    let loss = |w: &mut World, s: f64| {
        let mut f = w.get_mut::<SvdFactors>(e).unwrap();
        f.u = axpy_m(&s0.u, s, &du);
        f.s = axpy_v(&s0.s, s, &ds);
        f.v = axpy_m(&s0.v, s, &dv);
        w.get_mut::<AffineVelocity>(e).unwrap().0 = axpy_m(&c0, s, &dc);
        w.run_system_once(systems::constitutive::constitutive_model::<DruckerPrager>)
            .unwrap();
        dotm(&w.get::<DeformationGradient>(e).unwrap().0, &wf)
            + dotm(&w.get::<P2gAffine>(e).unwrap().0, &wa)
    };
    let fd = (loss(&mut w, FD_EPS) - loss(&mut w, -FD_EPS)) / (2.0 * FD_EPS);
    loss(&mut w, 0.0);
    w.get_mut::<DeformationGradientAdj>(e).unwrap().0 = wf;
    w.get_mut::<P2gAffineAdj>(e).unwrap().0 = wa;
    w.run_system_once(adjoint::constitutive::constitutive_model_adjoint::<DruckerPrager>)
        .unwrap();
    let g = w.get::<SvdFactorsAdj>(e).unwrap();
    let ad = dotm(&g.u, &du)
        + dotv(&g.s, &ds)
        + dotm(&g.v, &dv)
        + dotm(&w.get::<AffineVelocityAdj>(e).unwrap().0, &dc);
    check("constitutive<DruckerPrager>", fd, ad);
}

#[test]
fn p2g() {
    let mut rng = Rng::new(4);
    let (mut w, e) = world(&mut rng);
    let (x0, v0, a0) = (
        w.get::<Position>(e).unwrap().0.clone(),
        w.get::<Velocity>(e).unwrap().0.clone(),
        w.get::<P2gAffine>(e).unwrap().0.clone(),
    );
    let wg = rng.vs(NG * NG * NG);
    let (dxp, dv, da) = (rng.vs(N), rng.vs(N), rng.ms(N));
    let dxp: Vec<DVec3> = dxp.iter().map(|d| *d * 1e-3).collect();
    let loss = |w: &mut World, s: f64| {
        w.get_mut::<Position>(e).unwrap().0 = axpy_v(&x0, s, &dxp);
        w.get_mut::<Velocity>(e).unwrap().0 = axpy_v(&v0, s, &dv);
        w.get_mut::<P2gAffine>(e).unwrap().0 = axpy_m(&a0, s, &da);
        w.run_system_once(systems::grid_reset::grid_reset).unwrap();
        w.run_system_once(systems::p2g::p2g).unwrap();
        dotv(&w.resource::<Grid>().velocity, &wg)
    };
    let fd = (loss(&mut w, FD_EPS) - loss(&mut w, -FD_EPS)) / (2.0 * FD_EPS);
    loss(&mut w, 0.0);
    w.get_mut::<SubstepStart>(e).unwrap().x = x0;
    w.get_mut::<SubstepStart>(e).unwrap().v = v0;
    w.resource_mut::<GridAdj>().velocity = wg;
    w.run_system_once(adjoint::p2g::p2g_adjoint).unwrap();
    let ad = dotv(&w.get::<PositionAdj>(e).unwrap().0, &dxp)
        + dotv(&w.get::<VelocityAdj>(e).unwrap().0, &dv)
        + dotm(&w.get::<P2gAffineAdj>(e).unwrap().0, &da);
    check("p2g", fd, ad);
    // P2G overwrites every node's velocity, so its adjoint consumes the velocity adjoint.
    assert!(w
        .resource::<GridAdj>()
        .velocity
        .iter()
        .all(|g| *g == DVec3::ZERO));
}

#[test]
fn g2p() {
    let mut rng = Rng::new(5);
    let (mut w, e) = world(&mut rng);
    w.run_system_once(systems::grid_reset::grid_reset).unwrap();
    w.run_system_once(systems::p2g::p2g).unwrap();
    let x0 = w.get::<Position>(e).unwrap().0.clone();
    let gv0 = rng.vs(NG * NG * NG);
    let (wv, wc) = (rng.vs(N), rng.ms(N));
    let (dxp, dg) = (rng.vs(N), rng.vs(NG * NG * NG));
    let dxp: Vec<DVec3> = dxp.iter().map(|d| *d * 1e-3).collect();
    let loss = |w: &mut World, s: f64| {
        w.get_mut::<Position>(e).unwrap().0 = axpy_v(&x0, s, &dxp);
        w.resource_mut::<Grid>().velocity = axpy_v(&gv0, s, &dg);
        w.run_system_once(systems::g2p::g2p).unwrap();
        dotv(&w.get::<Velocity>(e).unwrap().0, &wv)
            + dotm(&w.get::<AffineVelocity>(e).unwrap().0, &wc)
    };
    let fd = (loss(&mut w, FD_EPS) - loss(&mut w, -FD_EPS)) / (2.0 * FD_EPS);
    loss(&mut w, 0.0);
    w.get_mut::<SubstepStart>(e).unwrap().x = x0;
    w.get_mut::<VelocityAdj>(e).unwrap().0 = wv;
    w.get_mut::<AffineVelocityAdj>(e).unwrap().0 = wc;
    w.run_system_once(adjoint::g2p::g2p_adjoint).unwrap();
    let ad = dotv(&w.get::<PositionAdj>(e).unwrap().0, &dxp)
        + dotv(&w.resource::<GridAdj>().velocity, &dg);
    check("g2p", fd, ad);
}

#[test]
fn advect() {
    let mut rng = Rng::new(6);
    let (mut w, e) = world(&mut rng);
    let (x0, v0) = (
        w.get::<Position>(e).unwrap().0.clone(),
        w.get::<Velocity>(e).unwrap().0.clone(),
    );
    let (wx, dxp, dv) = (rng.vs(N), rng.vs(N), rng.vs(N));
    let loss = |w: &mut World, s: f64| {
        w.get_mut::<Position>(e).unwrap().0 = axpy_v(&x0, s, &dxp);
        w.get_mut::<Velocity>(e).unwrap().0 = axpy_v(&v0, s, &dv);
        w.run_system_once(systems::advect::advect).unwrap();
        dotv(&w.get::<Position>(e).unwrap().0, &wx)
    };
    let fd = (loss(&mut w, FD_EPS) - loss(&mut w, -FD_EPS)) / (2.0 * FD_EPS);
    w.get_mut::<Position>(e).unwrap().0 = x0;
    w.get_mut::<Velocity>(e).unwrap().0 = v0;
    w.get_mut::<PositionAdj>(e).unwrap().0 = wx;
    w.run_system_once(adjoint::advect::advect_adjoint).unwrap();
    check(
        "advect",
        fd,
        dotv(&w.get::<PositionAdj>(e).unwrap().0, &dxp)
            + dotv(&w.get::<VelocityAdj>(e).unwrap().0, &dv),
    );
}

#[test]
fn gravity_and_domain_walls() {
    let mut rng = Rng::new(7);
    let (mut w, _) = world(&mut rng);
    w.run_system_once(systems::grid_reset::grid_reset).unwrap();
    w.run_system_once(systems::p2g::p2g).unwrap();
    // Every node non-empty, so gravity acts everywhere and the walls see real velocities.
    w.resource_mut::<Grid>()
        .nodes
        .iter_mut()
        .for_each(|n| n.mass = 1.0);
    let len = NG * NG * NG;
    let v0 = rng.vs(len);
    let (wv, dv, dg) = (rng.vs(len), rng.vs(len), rng.v());
    let g0 = w.resource::<SimParams>().gravity;
    let loss = |w: &mut World, s: f64| {
        w.resource_mut::<Grid>().velocity = axpy_v(&v0, s, &dv);
        w.resource_mut::<SimParams>().gravity = g0 + dg * s;
        w.run_system_once(systems::gravity::gravity).unwrap();
        w.run_system_once(systems::grid_collision::domain_walls)
            .unwrap();
        dotv(&w.resource::<Grid>().velocity, &wv)
    };
    let fd = (loss(&mut w, FD_EPS) - loss(&mut w, -FD_EPS)) / (2.0 * FD_EPS);
    w.resource_mut::<SimParams>().gravity = g0;
    w.resource_mut::<Grid>().velocity = v0.clone();
    w.run_system_once(systems::gravity::gravity).unwrap();
    let after_gravity = w.resource::<Grid>().velocity.clone();
    w.resource_mut::<WallInputVelocity>().0 = after_gravity;
    w.resource_mut::<GridAdj>().velocity = wv;
    w.run_system_once(adjoint::grid_collision::domain_walls_adjoint)
        .unwrap();
    w.run_system_once(adjoint::gravity::gravity_adjoint)
        .unwrap();
    let ad = dotv(&w.resource::<GridAdj>().velocity, &dv) + w.resource::<GravityAdj>().0.dot(dg);
    check("gravity + domain walls", fd, ad);
}

#[test]
fn constitutive_elastic() {
    use powderlab::materials::elastic::Elastic;
    let mut rng = Rng::new(8);
    let (mut w, e) = world(&mut rng);
    w.entity_mut(e).remove::<DruckerPrager>();
    w.entity_mut(e).insert(Elastic {
        density: 1000.0,
        youngs_modulus: 1e5,
        poisson_ratio: 0.3,
    });
    w.run_system_once(systems::svd::svd).unwrap();
    let s0 = w.get::<SvdFactors>(e).unwrap().clone();
    let ft0 = w.get::<TrialDeformation>(e).unwrap().0.clone();
    let (wf, wa) = (rng.ms(N), rng.ms(N));
    let (du, ds, dft) = (rng.ms(N), rng.vs(N), rng.ms(N));
    let ds: Vec<DVec3> = ds.iter().map(|d| *d * 0.01).collect();
    let loss = |w: &mut World, s: f64| {
        let mut f = w.get_mut::<SvdFactors>(e).unwrap();
        f.u = axpy_m(&s0.u, s, &du);
        f.s = axpy_v(&s0.s, s, &ds);
        w.get_mut::<TrialDeformation>(e).unwrap().0 = axpy_m(&ft0, s, &dft);
        w.run_system_once(systems::constitutive::constitutive_model::<Elastic>)
            .unwrap();
        dotm(&w.get::<DeformationGradient>(e).unwrap().0, &wf)
            + dotm(&w.get::<P2gAffine>(e).unwrap().0, &wa)
    };
    let fd = (loss(&mut w, FD_EPS) - loss(&mut w, -FD_EPS)) / (2.0 * FD_EPS);
    loss(&mut w, 0.0);
    w.get_mut::<DeformationGradientAdj>(e).unwrap().0 = wf;
    w.get_mut::<P2gAffineAdj>(e).unwrap().0 = wa;
    w.run_system_once(adjoint::constitutive::constitutive_model_adjoint::<Elastic>)
        .unwrap();
    let g = w.get::<SvdFactorsAdj>(e).unwrap();
    let ad =
        dotm(&g.u, &du) + dotv(&g.s, &ds) + dotm(&w.get::<TrialDeformationAdj>(e).unwrap().0, &dft);
    check("constitutive<Elastic>", fd, ad);
}

/// A spinning, translating box tool and a static cup: the contact adjoints with respect to the
/// velocities (grid or particle), the positions (particles), and the tool's pose and velocity.
fn collider_world(rng: &mut Rng, soft_band: bool) -> (World, Entity, Entity) {
    use powderlab::adjoint::grid_collision::{ColliderAdj, ColliderInputVelocity};
    use powderlab::math::pose::{quat_from_rotation_vector, Pose};
    use powderlab::math::sdf::Shape;
    let (mut w, e) = world(rng);
    w.insert_resource(ColliderInputVelocity(vec![DVec3::ZERO; NG * NG * NG]));
    let tool = w
        .spawn((
            Collider {
                name: "paddle".into(),
                index: 0,
                kind: ColliderKind::Tool,
                shape: Shape::Box {
                    half_extents: [0.012, 0.02, 0.015],
                },
                friction: 0.3,
                contact: ContactMode::Separate,
                band: 0.01,
                soft_band,
                bounding_radius: f64::INFINITY,
                particle_contact: true,
                soft_particle_contact: false,
            },
            ColliderPose {
                pose: Pose {
                    translation: DVec3::new(0.0601234, 0.0598765, 0.0612345),
                    rotation: quat_from_rotation_vector(DVec3::new(0.2, -0.4, 0.3)),
                },
                linear: DVec3::new(0.3, -0.2, 0.1),
                angular: DVec3::new(1.1, 0.4, -0.7),
            },
            ColliderAdj::default(),
        ))
        .id();
    w.spawn((
        Collider {
            name: "cup".into(),
            index: 1,
            kind: ColliderKind::Container,
            shape: Shape::Cup {
                outer_radius: 0.04,
                height: 0.06,
                wall_thickness: 0.002,
                floor_thickness: 0.003,
                fillet_radius: None,
            },
            friction: 0.4,
            contact: ContactMode::Slip,
            band: 0.01,
            soft_band: false,
            bounding_radius: f64::INFINITY,
            particle_contact: true,
            soft_particle_contact: false,
        },
        ColliderPose {
            pose: Pose {
                translation: DVec3::new(0.0612345, 0.0301234, 0.0598765),
                rotation: glam::DQuat::IDENTITY,
            },
            ..Default::default()
        },
        ColliderAdj::default(),
    ));
    w.resource_mut::<Grid>()
        .nodes
        .iter_mut()
        .for_each(|n| n.mass = 1.0);
    (w, e, tool)
}

fn perturb_tool(w: &mut World, tool: Entity, base: ColliderPose, s: f64, d: &[DVec3; 4]) {
    use powderlab::math::pose::quat_from_rotation_vector;
    let mut p = base;
    p.pose.translation += d[0] * s;
    p.pose.rotation = (quat_from_rotation_vector(d[1] * s) * base.pose.rotation).normalize();
    p.linear += d[2] * s;
    p.angular += d[3] * s;
    *w.get_mut::<ColliderPose>(tool).unwrap() = p;
}

fn tool_adj_dot(w: &World, tool: Entity, d: &[DVec3; 4]) -> f64 {
    let a = w
        .get::<powderlab::adjoint::grid_collision::ColliderAdj>(tool)
        .unwrap();
    a.translation.dot(d[0]) + a.rotation.dot(d[1]) + a.linear.dot(d[2]) + a.angular.dot(d[3])
}

#[test]
fn collider_contact() {
    collider_contact_with(false);
}

/// The tool's grid contact blended in across its band (`soft_band`): the blend weight depends on
/// the tool's pose, which the adjoint must carry through `φ̄`.
#[test]
fn collider_contact_soft_band() {
    collider_contact_with(true);
}

fn collider_contact_with(soft_band: bool) {
    use powderlab::adjoint::grid_collision::ColliderInputVelocity;
    let mut rng = Rng::new(9);
    let (mut w, _, tool) = collider_world(&mut rng, soft_band);
    let len = NG * NG * NG;
    let (v0, wv, dv) = (rng.vs(len), rng.vs(len), rng.vs(len));
    let d = [rng.v(), rng.v(), rng.v(), rng.v()];
    let base = *w.get::<ColliderPose>(tool).unwrap();
    let loss = |w: &mut World, s: f64| {
        w.resource_mut::<Grid>().velocity = axpy_v(&v0, s, &dv);
        perturb_tool(w, tool, base, s, &d);
        w.run_system_once(systems::grid_collision::collider_contact)
            .unwrap();
        dotv(&w.resource::<Grid>().velocity, &wv)
    };
    let eps = 1e-8;
    let fd = (loss(&mut w, eps) - loss(&mut w, -eps)) / (2.0 * eps);
    perturb_tool(&mut w, tool, base, 0.0, &d);
    w.resource_mut::<ColliderInputVelocity>().0 = v0;
    w.resource_mut::<GridAdj>().velocity = wv;
    w.run_system_once(adjoint::grid_collision::collider_contact_adjoint)
        .unwrap();
    let ad = dotv(&w.resource::<GridAdj>().velocity, &dv) + tool_adj_dot(&w, tool, &d);
    check("collider_contact", fd, ad);
}

#[test]
fn particle_collision() {
    particle_collision_with(false);
}

/// The soft projection (`soft_particle_contact`) on both colliders.
#[test]
fn particle_collision_soft() {
    particle_collision_with(true);
}

fn particle_collision_with(soft: bool) {
    use powderlab::adjoint::particle_collision::ParticleCollisionInput;
    let mut rng = Rng::new(10);
    let (mut w, e, tool) = collider_world(&mut rng, false);
    for mut c in w.query::<&mut Collider>().iter_mut(&mut w) {
        c.soft_particle_contact = soft;
    }
    // Particles just outside the paddle's faces and the cup's inner wall, moving into them.
    let x0: Vec<DVec3> = (0..N)
        .map(|_| DVec3::new(0.06, 0.06, 0.06) + rng.v() * 0.03)
        .collect();
    let v0: Vec<DVec3> = (0..N).map(|_| rng.v() * 2.0).collect();
    let (wv, dxp, dv) = (rng.vs(N), rng.vs(N), rng.vs(N));
    let d = [rng.v(), rng.v(), rng.v(), rng.v()];
    let base = *w.get::<ColliderPose>(tool).unwrap();
    w.entity_mut(e).insert(ParticleCollisionInput::default());
    let loss = |w: &mut World, s: f64| {
        w.get_mut::<Position>(e).unwrap().0 = axpy_v(&x0, s, &dxp);
        w.get_mut::<Velocity>(e).unwrap().0 = axpy_v(&v0, s, &dv);
        perturb_tool(w, tool, base, s, &d);
        w.run_system_once(systems::particle_collision::particle_collision)
            .unwrap();
        dotv(&w.get::<Velocity>(e).unwrap().0, &wv)
    };
    let eps = 1e-8;
    let fd = (loss(&mut w, eps) - loss(&mut w, -eps)) / (2.0 * eps);
    perturb_tool(&mut w, tool, base, 0.0, &d);
    w.get_mut::<Position>(e).unwrap().0 = x0;
    w.get_mut::<ParticleCollisionInput>(e).unwrap().0 = v0;
    w.get_mut::<VelocityAdj>(e).unwrap().0 = wv;
    w.run_system_once(adjoint::particle_collision::particle_collision_adjoint)
        .unwrap();
    let ad = dotv(&w.get::<PositionAdj>(e).unwrap().0, &dxp)
        + dotv(&w.get::<VelocityAdj>(e).unwrap().0, &dv)
        + tool_adj_dot(&w, tool, &d);
    check(
        if soft {
            "particle_collision (soft)"
        } else {
            "particle_collision"
        },
        fd,
        ad,
    );
}

#[test]
fn tool_move() {
    use powderlab::adjoint::grid_collision::ColliderAdj;
    use powderlab::adjoint::tool_move::ControlAdj;
    let mut rng = Rng::new(11);
    let (mut w, _, tool) = collider_world(&mut rng, false);
    let u0 = [0.003, -0.002, 0.001, 0.02, 0.05, -0.03];
    let du: [f64; 6] = std::array::from_fn(|_| rng.f());
    let base = *w.get::<ColliderPose>(tool).unwrap();
    let d = [rng.v(), rng.v(), DVec3::ZERO, DVec3::ZERO];
    let (wt, wr, wl, wa) = (rng.v(), rng.m(), rng.v(), rng.v());
    w.entity_mut(tool)
        .insert((Control { per_step: vec![u0] }, ControlAdj(vec![[0.0; 6]])));
    let loss = |w: &mut World, s: f64| {
        let u: [f64; 6] = std::array::from_fn(|k| u0[k] + s * du[k]);
        w.get_mut::<Control>(tool).unwrap().per_step = vec![u];
        perturb_tool(w, tool, base, s, &d);
        w.run_system_once(systems::tool_move::tool_move).unwrap();
        let p = *w.get::<ColliderPose>(tool).unwrap();
        let r = DMat3::from_quat(p.pose.rotation);
        wt.dot(p.pose.translation) + dotm(&[r], &[wr]) + wl.dot(p.linear) + wa.dot(p.angular)
    };
    let fd = (loss(&mut w, FD_EPS) - loss(&mut w, -FD_EPS)) / (2.0 * FD_EPS);
    // Adjoint of the outputs: t̄ = wt; θ̄ from tr(W_Rᵀ·R) with δR = [δθ]×R: axial parts of R·W_Rᵀ.
    perturb_tool(&mut w, tool, base, 0.0, &d);
    w.get_mut::<Control>(tool).unwrap().per_step = vec![u0];
    w.run_system_once(systems::tool_move::tool_move).unwrap();
    let r1 = DMat3::from_quat(w.get::<ColliderPose>(tool).unwrap().pose.rotation);
    let a = r1 * wr.transpose();
    // glam is column-major: a.z_axis.y is A[1][2].
    let g_theta = DVec3::new(
        a.z_axis.y - a.y_axis.z,
        a.x_axis.z - a.z_axis.x,
        a.y_axis.x - a.x_axis.y,
    );
    *w.get_mut::<ColliderAdj>(tool).unwrap() = ColliderAdj {
        friction: 0.0,
        translation: wt,
        rotation: g_theta,
        linear: wl,
        angular: wa,
    };
    w.run_system_once(adjoint::tool_move::tool_move_adjoint)
        .unwrap();
    let g = w.get::<ColliderAdj>(tool).unwrap();
    let gu = w.get::<ControlAdj>(tool).unwrap().0[0];
    let ad =
        g.translation.dot(d[0]) + g.rotation.dot(d[1]) + (0..6).map(|k| gu[k] * du[k]).sum::<f64>();
    check("tool_move", fd, ad);
}

/// Each adjoint stage that writes particle fields raises [`NonFiniteSeen`] when it writes a
/// non-finite value into one (the backward driver scans those fields, to name the particle,
/// only then), and does not raise it on finite input: a NaN put into the adjoint a stage reads
/// must come out flagged.
#[test]
fn stages_flag_the_non_finite_values_they_write() {
    let flagged = |w: &mut World| w.resource::<NonFiniteSeen>().take();
    let fresh = |seed: u64| {
        let mut rng = Rng::new(seed);
        let (mut w, e) = world(&mut rng);
        w.run_system_once(systems::grid_reset::grid_reset).unwrap();
        w.run_system_once(systems::p2g::p2g).unwrap();
        w.run_system_once(systems::svd::svd).unwrap();
        let x = w.get::<Position>(e).unwrap().0.clone();
        let v = w.get::<Velocity>(e).unwrap().0.clone();
        let f = w.get::<DeformationGradient>(e).unwrap().0.clone();
        let c = w.get::<AffineVelocity>(e).unwrap().0.clone();
        let mut st = w.get_mut::<SubstepStart>(e).unwrap();
        (st.x, st.v, st.f, st.c) = (x, v, f, c);
        (w, e, rng)
    };
    // Random input adjoints, with one NaN entry when `bad`.
    fn vs(rng: &mut Rng, n: usize, bad: bool) -> Vec<DVec3> {
        let mut g = rng.vs(n);
        if bad {
            g[5].y = f64::NAN;
        }
        g
    }
    fn ms(rng: &mut Rng, bad: bool) -> Vec<DMat3> {
        let mut g = rng.ms(N);
        if bad {
            g[5].y_axis.z = f64::NAN;
        }
        g
    }
    // (stage, how its input adjoint is set before it runs)
    type Setup = fn(&mut World, Entity, &mut Rng, bool);
    let cases: [(&str, Setup); 6] = [
        ("advect", |w, e, rng, bad| {
            w.get_mut::<PositionAdj>(e).unwrap().0 = vs(rng, N, bad);
            w.run_system_once(adjoint::advect::advect_adjoint).unwrap();
        }),
        ("g2p", |w, e, rng, bad| {
            w.get_mut::<VelocityAdj>(e).unwrap().0 = vs(rng, N, bad);
            w.run_system_once(adjoint::g2p::g2p_adjoint).unwrap();
        }),
        ("p2g", |w, _, rng, bad| {
            // Every node, so that some non-empty node (the only ones it reads) has the NaN.
            let n = w.resource::<GridAdj>().velocity.len();
            let mut g = vs(rng, n, false);
            if bad {
                g.iter_mut().for_each(|v| v.z = f64::NAN);
            }
            w.resource_mut::<GridAdj>().velocity = g;
            w.run_system_once(adjoint::p2g::p2g_adjoint).unwrap();
        }),
        ("constitutive", |w, e, rng, bad| {
            w.get_mut::<P2gAffineAdj>(e).unwrap().0 = ms(rng, bad);
            w.run_system_once(adjoint::constitutive::constitutive_model_adjoint::<DruckerPrager>)
                .unwrap();
        }),
        ("svd", |w, e, rng, bad| {
            w.get_mut::<SvdFactorsAdj>(e).unwrap().s = vs(rng, N, bad);
            w.run_system_once(adjoint::svd::svd_adjoint).unwrap();
        }),
        ("deformation_update", |w, e, rng, bad| {
            w.get_mut::<TrialDeformationAdj>(e).unwrap().0 = ms(rng, bad);
            w.run_system_once(adjoint::deformation_update::deformation_update_adjoint)
                .unwrap();
        }),
    ];
    for (k, (stage, run)) in cases.iter().enumerate() {
        for bad in [false, true] {
            let (mut w, e, mut rng) = fresh(100 + k as u64);
            run(&mut w, e, &mut rng, bad);
            assert_eq!(flagged(&mut w), bad, "{stage}, NaN in its input: {bad}");
        }
    }
}

/// The forward mirror of the test above: each forward stage that checks what it writes tests
/// each value while it holds it and, only when one is not finite, scans the field to name the
/// first bad particle or node. A NaN put into one particle's input must be reported with that
/// stage, field and index, and finite input must report nothing.
#[test]
fn forward_stages_report_the_non_finite_values_they_write() {
    // Particle 5 sits alone at the low corner: its stencil (nodes 1..=3 on each axis) holds the
    // only particle that reaches node (1, 1, 1); every other one starts at node 2 or above.
    const LONE: usize = 5;
    let lone_x = DVec3::splat(0.015);
    type Setup = fn(&mut World, Entity, bool);
    // (stage, field, how the input is set and the stage run, expected index)
    let cases: [(&str, &str, Setup); 4] = [
        ("p2g", "grid velocity", |w, e, bad| {
            if bad {
                w.get_mut::<P2gAffine>(e).unwrap().0[LONE].y_axis.z = f64::NAN;
            }
            w.run_system_once(systems::grid_reset::grid_reset).unwrap();
            w.run_system_once(systems::p2g::p2g).unwrap();
        }),
        ("constitutive", "F", |w, e, bad| {
            if bad {
                w.get_mut::<SvdFactors>(e).unwrap().u[LONE].x_axis.y = f64::NAN;
            }
            w.run_system_once(systems::constitutive::constitutive_model::<DruckerPrager>)
                .unwrap();
        }),
        ("g2p", "v", |w, _, bad| {
            let mut g = w.resource_mut::<Grid>();
            g.velocity
                .iter_mut()
                .for_each(|v| *v = DVec3::new(0.1, -0.2, 0.3));
            if bad {
                let i = g.index(1, 1, 1);
                g.velocity[i].x = f64::NAN;
            }
            w.run_system_once(systems::g2p::g2p).unwrap();
        }),
        ("advect", "x", |w, e, bad| {
            if bad {
                w.get_mut::<Velocity>(e).unwrap().0[LONE].z = f64::NAN;
            }
            w.run_system_once(systems::advect::advect).unwrap();
        }),
    ];
    for (k, (stage, field, run)) in cases.iter().enumerate() {
        for bad in [false, true] {
            let mut rng = Rng::new(200 + k as u64);
            let (mut w, e) = world(&mut rng);
            w.get_mut::<Position>(e).unwrap().0[LONE] = lone_x;
            run(&mut w, e, bad);
            let fault = w.resource_mut::<Health>().fault.take();
            if !bad {
                assert_eq!(fault, None, "{stage} on finite input");
                continue;
            }
            let fault = fault.unwrap_or_else(|| panic!("{stage} did not report the NaN"));
            let index = if *stage == "p2g" {
                w.resource::<Grid>().index(1, 1, 1)
            } else {
                LONE
            };
            assert_eq!(
                (fault.stage, fault.field, fault.index),
                (*stage, *field, index),
                "{fault}"
            );
        }
    }
}
