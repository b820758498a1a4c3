//! Does a skill's motion stay clear of the domain's top wall layer and of the cups' walls? For
//! each Θ, one rollout of the scene: the highest particle, the most particles inside the top
//! particles whose stencils reach the top wall layer at once (where the domain wall's contact and
//! friction act on the grid nodes: the outer `walls.cells` node layers), and the
//! smallest signed distance of the spoon's surface (its mesh vertices) to each container
//! (negative: the spoon passed through the wall), each with the step it happened at.
//!
//! ```sh
//! cargo run --release --example skill_clearance -- SCENE THETA [THETA ...]
//! ```
use powderlab::components::ColliderKind;
use powderlab::lab::optim::problem::Problem;
use powderlab::lab::study::error_vs_time::parse_theta;
use powderlab::scene::Scene;

fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().collect();
    if a.len() < 3 {
        anyhow::bail!("usage: skill_clearance SCENE THETA [THETA ...]");
    }
    let scene = Scene::load(&a[1])?;
    let s = &scene.simulation;
    // The layer is the nodes j ≥ n − cells; a particle's quadratic stencil reaches node
    // ⌊y/dx − 0.5⌋ + 2, so it touches the layer from y = (n − cells − 1.5)·dx.
    let layer = s.domain_min.1 + (s.cells.1 - s.walls.cells) as f64 * s.dx;
    let top_layer = layer - 1.5 * s.dx;
    let problem = Problem::new(scene.clone(), 1 << 30)?;
    let tool = &scene.colliders[problem.tool];
    let vertices: Vec<glam::DVec3> = tool
        .shape
        .mesh()
        .vertices
        .iter()
        .map(|v| glam::DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64))
        .collect();
    println!("top wall layer from y = {layer:.4} m; a particle's stencil reaches it from y = {top_layer:.4} m");
    for t in &a[2..] {
        let theta = parse_theta(t)?;
        let mut sim = problem.simulation(theta, false)?;
        let (mut max_y, mut max_y_step, mut in_layer, mut in_layer_step) = (f64::MIN, 0, 0, 0);
        let mut closest: Vec<(String, f64, usize)> = Vec::new();
        for step in 1..=sim.horizon {
            sim.step()?;
            for b in sim.body_states() {
                let n = b.x.iter().filter(|x| x.y >= top_layer).count();
                if n > in_layer {
                    (in_layer, in_layer_step) = (n, step);
                }
                for x in &b.x {
                    if x.y > max_y {
                        (max_y, max_y_step) = (x.y, step);
                    }
                }
            }
            let poses = sim.collider_poses();
            let spoon = poses[problem.tool].3;
            for (name, kind, shape, pose) in &poses {
                if *kind != ColliderKind::Container {
                    continue;
                }
                let phi = vertices
                    .iter()
                    .map(|v| shape.sdf(pose.to_local(spoon.to_world(*v))).0)
                    .fold(f64::INFINITY, f64::min);
                match closest.iter_mut().find(|c| &c.0 == name) {
                    Some(c) if phi < c.1 => (c.1, c.2) = (phi, step),
                    Some(_) => {}
                    None => closest.push((name.clone(), phi, step)),
                }
            }
        }
        println!(
            "Θ {theta:?}: {} steps; highest particle {max_y:.4} m (step {max_y_step}); at most {in_layer} particles reaching the top wall layer (step {in_layer_step}); spoon to {}",
            sim.horizon,
            closest
                .iter()
                .map(|(n, p, s)| format!("{n} {:.4} m (step {s})", p))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    Ok(())
}
