//! Where does the powder a push plan leaves outside its region lie: under the blade's edge at
//! the boundary, spread past the blade's ends, left behind where the strokes started, or off
//! the plate?
//!
//! `cargo run --release --example push_residue -- SCENE PLAN_JSON`: replays the strokes of a
//! plan (`plan-METHOD.json`, as `powderlab plan` or `study planning` writes it) on `SCENE` (the
//! instance's scene), each from the contact the plan recorded, and prints after each stroke the
//! share in the region and a map of the grains outside it: rows by distance from the boundary
//! along the stroke (mm, negative on the powder's side), columns by z (mm), the count of grains
//! in each 5 mm cell, and the grains off the plate, by where they left it.

use powderlab::lab::plan::push::{Push, PushNode};
use powderlab::lab::plan::stroke::Stroke;
use powderlab::scene::Scene;
use std::sync::Arc;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    anyhow::ensure!(args.len() == 3, "usage: push_residue SCENE PLAN_JSON");
    let scene = Scene::load(&args[1])?;
    let plan: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&args[2])?)?;
    let mut push = Push::new(scene, 0, None)?;
    let region = push.region();
    let mut n = push.start()?;
    let strokes = plan["strokes"]
        .as_array()
        .ok_or_else(|| anyhow::anyhow!("{}: no strokes", args[2]))?;
    for (k, s) in strokes.iter().enumerate() {
        let phi: [f64; 5] = serde_json::from_value(s["phi"].clone())?;
        n.contact = s["contact"]
            .as_f64()
            .ok_or_else(|| anyhow::anyhow!("stroke {k}: no contact"))?;
        let st = Stroke::from_phi(&phi);
        let mut sim = push.stroke_simulation(&n, &st)?;
        let steps = sim.horizon;
        sim.run(steps, |_| {})?;
        let states = sim.body_states();
        let xs: Vec<_> = states.iter().flat_map(|b| b.x.iter().copied()).collect();
        let share = region.share(xs.iter());
        println!(
            "stroke {k}: contact z {:.1} mm, {st:?}; in region {:.1} % (plan: {:.1} %)",
            n.contact * 1e3,
            100.0 * share,
            100.0 * s["in_region"].as_f64().unwrap_or(f64::NAN)
        );
        let (c, h) = (region.centre, region.half);
        let plate_top = c.y + h.y;
        let mut off = 0;
        // Off the plate: past its ends along the stroke, past its sides, or fallen below it.
        let mut off_by = [0usize; 3];
        let mut cells = std::collections::BTreeMap::<(i64, i64), usize>::new();
        let boundary = push.plan.boundary;
        let side = push.plan.class.side();
        for x in xs.iter().filter(|x| !region.inside(**x)) {
            if x.y < plate_top - 1e-3 || (x.z - c.z).abs() > h.z || (x.x - c.x).abs() > h.x {
                off += 1;
                off_by[if (x.x - c.x).abs() > h.x {
                    0
                } else if (x.z - c.z).abs() > h.z {
                    1
                } else {
                    2
                }] += 1;
                continue;
            }
            // Distance behind the boundary, along the stroke (mm).
            let behind = -side * (boundary - x.x) * 1e3;
            let key = (
                (behind / 5.0).floor() as i64,
                (x.z * 1e3 / 5.0).floor() as i64,
            );
            *cells.entry(key).or_default() += 1;
        }
        let outside = xs.len() - xs.iter().filter(|x| region.inside(**x)).count();
        println!(
            "  outside: {outside} of {} grains, {off} off the plate ({} past its ends along x, \
             {} past its sides along z, {} below its top)",
            xs.len(),
            off_by[0],
            off_by[1],
            off_by[2]
        );
        let zs: std::collections::BTreeSet<i64> = cells.keys().map(|k| k.1).collect();
        let rows: std::collections::BTreeSet<i64> = cells.keys().map(|k| k.0).collect();
        print!("  behind (mm) \\ z (mm):");
        for z in &zs {
            print!("{:>6}", z * 5);
        }
        println!();
        for r in &rows {
            print!("  {:>8}            ", r * 5);
            for z in &zs {
                print!("{:>6}", cells.get(&(*r, *z)).copied().unwrap_or(0));
            }
            println!();
        }
        n = PushNode {
            state: Arc::new(states),
            in_region: share,
            contact: n.contact,
            stroke: None,
            strokes: n.strokes + 1,
            key: format!("{}/s", n.key),
        };
    }
    Ok(())
}
