//! The substep schedule holds only the systems a scene needs: free fall (elastic, no colliders)
//! against the transport task (sand, a tool, thin-walled cups).

mod common;

#[test]
fn systems_differ_with_the_scene() {
    let ff = common::build(&common::load("free_fall.ron"), 1).system_names();
    let pt = common::build(&common::load("powder_transport.ron"), 1).system_names();
    println!("free_fall:        {}", ff.join(" → "));
    println!("powder_transport: {}", pt.join(" → "));
    assert_eq!(
        ff,
        [
            "grid_reset::grid_reset",
            "deformation_update::deformation_update",
            "svd::svd",
            "constitutive::constitutive_model<elastic::Elastic>",
            "p2g::p2g",
            "gravity::gravity",
            "grid_collision::domain_walls",
            "g2p::g2p",
            "advect::advect",
        ]
    );
    assert_eq!(
        pt,
        [
            "grid_reset::grid_reset",
            "deformation_update::deformation_update",
            "svd::svd",
            "constitutive::constitutive_model<drucker_prager::DruckerPrager>",
            "p2g::p2g",
            "tool_move::tool_move",
            "gravity::gravity",
            "grid_collision::collider_contact",
            "grid_collision::domain_walls",
            "g2p::g2p",
            "particle_collision::particle_collision",
            "advect::advect",
        ]
    );
}

#[test]
fn two_materials_get_two_ordered_constitutive_systems() {
    let src = r#"Scene(
        simulation: (cells: (20, 20, 20), dx: 0.01, steps: Some(1)),
        materials: { "a": Elastic((youngs_modulus: 1e4)), "b": DruckerPrager((youngs_modulus: 1e4)) },
        bodies: [
            (name: "x", material: "a", fill: Box(min: (0.05, 0.05, 0.05), max: (0.08, 0.08, 0.08))),
            (name: "y", material: "b", fill: Box(min: (0.1, 0.05, 0.1), max: (0.13, 0.08, 0.13))),
        ],
    )"#;
    let mut sim = common::build(&common::parse(src).unwrap(), 1);
    let names = sim.system_names();
    assert!(
        names
            .iter()
            .filter(|n| n.starts_with("constitutive::"))
            .count()
            == 2,
        "{names:?}"
    );
    sim.step().unwrap();
    common::assert_finite(&mut sim);
}
