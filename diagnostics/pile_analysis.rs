//! Why a pile's flank angle is what it is: runs the pile of `powderlab validate pile_angle` and
//! prints the flank fit, whether the slab stayed in plane strain (its particles' z-spread), and
//! the stress state at the end (the in-plane friction angle each particle mobilises and its
//! out-of-plane deviatoric stress), against the plane-strain angle and Davis's simple-shear angle.
//!
//! `cargo run --release --example pile_analysis -- PHI_DEG [CELLS=40] [T_END/T_c=6] [RAMP/T_c=0]`
//!
//! With RAMP > 0, gravity is ramped in over that time ([`smooth_ramp`]) instead of all at once.

use powderlab::components::{Body, DeformationGradient, SimParams};
use powderlab::lab::validate::column::cauchy;
use powderlab::lab::validate::pile::{
    davis_angle_deg, flank_of, pile_collapse, plane_strain_angle_deg, Pile,
};
use powderlab::lab::validate::{collapse_scene, normalised_deposit, smooth_ramp};
use powderlab::scene::Scene;
use powderlab::sim::{SimOptions, Simulation};

fn arg<T: std::str::FromStr>(k: usize, default: T) -> T {
    std::env::args()
        .nth(k)
        .map(|s| s.parse().ok().expect("a number"))
        .unwrap_or(default)
}

fn quantiles(mut v: Vec<f64>, qs: &[f64]) -> String {
    v.sort_by(|a, b| a.total_cmp(b));
    qs.iter()
        .map(|q| format!("{:.3}", v[((v.len() - 1) as f64 * q) as usize]))
        .collect::<Vec<_>>()
        .join(" / ")
}

fn main() -> anyhow::Result<()> {
    let phi: f64 = arg(1, 30.0);
    let cells: usize = arg(2, 40);
    let t_end: f64 = arg(3, 6.0);
    let ramp: f64 = arg(4, 0.0);
    let c = pile_collapse(&Pile {
        friction_deg: phi,
        cells_across: cells,
    });
    let scene = Scene::parse(&collapse_scene(&c), std::path::Path::new("<pile>"))?;
    let mut sim = Simulation::new(&scene, &SimOptions::default())?;
    let dx = scene.simulation.dx;
    let tc = (c.aspect * c.length / 9.81).sqrt();
    let g = glam::DVec3::from(scene.simulation.gravity);
    let z0: Vec<f64> = sim.body_states()[0].x.iter().map(|x| x.z / dx).collect();
    let steps = (t_end * tc / scene.simulation.dt).ceil() as usize;
    // (in-plane sin φ_m, (−σ_zz − p)/p) of every particle under compression, at the last step.
    let mut stress: Vec<(f64, f64)> = Vec::new();
    for k in 1..=steps {
        sim.step_with(|world, t| {
            world.resource_mut::<SimParams>().gravity = g * smooth_ramp(t, ramp * tc);
            if k < steps || !stress.is_empty() {
                return;
            }
            let mut q = world.query::<(&Body, &DeformationGradient)>();
            let (b, f) = q.iter(world).next().expect("one body");
            let (mu, lambda) = b.lame;
            for f in &f.0 {
                let s = cauchy(*f, mu, lambda);
                let (sxx, syy, szz, sxy) = (s.x_axis.x, s.y_axis.y, s.z_axis.z, s.y_axis.x);
                let p = -(sxx + syy + szz) / 3.0;
                let p2 = -(sxx + syy) / 2.0;
                let r = (((sxx - syy) / 2.0).powi(2) + sxy * sxy).sqrt();
                if p2 > 0.0 && p > 0.0 {
                    stress.push(((r / p2).min(1.0), (-szz - p) / p));
                }
            }
        })?;
    }
    let st = sim.body_states();
    let deposit = normalised_deposit(&st[0].x, dx, c.length);
    println!(
        "φ = {phi}°, {cells} cells, {t_end} T_c, gravity ramp {ramp} T_c; {} particles",
        deposit.len()
    );
    println!(
        "reference angles: triaxial φ {phi:.1}°, plane strain {:.1}°, Davis simple shear {:.1}°",
        plane_strain_angle_deg(phi),
        davis_angle_deg(phi)
    );
    match flank_of(&c, &deposit) {
        Some(f) => println!(
            "flank {:.2}° ({} points, RMS {:.2} cells), pile height {:.3} L0",
            f.angle_deg,
            f.points,
            f.rms * cells as f64,
            f.height
        ),
        None => println!("no flank"),
    }
    let qs = [0.01, 0.05, 0.5, 0.95, 0.99];
    println!(
        "z / dx at 1/5/50/95/99 %: start {}, end {}",
        quantiles(z0, &qs),
        quantiles(st[0].x.iter().map(|x| x.z / dx).collect(), &qs)
    );
    println!(
        "mobilised in-plane friction angle (deg) at 50/90/99 %: {} of {} particles in compression",
        quantiles(
            stress.iter().map(|s| s.0.asin().to_degrees()).collect(),
            &[0.5, 0.9, 0.99]
        ),
        stress.len()
    );
    println!(
        "out-of-plane deviatoric stress s_zz/p at 10/50/90 %: {}",
        quantiles(stress.iter().map(|s| s.1).collect(), &[0.1, 0.5, 0.9])
    );
    Ok(())
}
