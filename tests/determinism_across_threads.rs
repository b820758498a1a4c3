//! The same scene gives bitwise identical final states on 1 and 2 threads: P2G scatters in a
//! fixed order (x-slab colouring), every other stage is a per-element map.

mod common;

fn final_state(name: &str, threads: usize, steps: usize) -> Vec<powderlab::components::BodyState> {
    let mut sim = common::build(&common::load(name), threads);
    sim.run(steps, |_| {}).unwrap();
    sim.body_states()
}

#[test]
fn sand_box_is_bitwise_identical_on_1_and_2_threads() {
    let a = final_state("sand_box.ron", 1, 3);
    let b = final_state("sand_box.ron", 2, 3);
    assert_eq!(a, b);
}

#[test]
fn powder_transport_is_bitwise_identical_on_1_and_2_threads() {
    let a = final_state("powder_transport.ron", 1, 25);
    let b = final_state("powder_transport.ron", 2, 25);
    assert_eq!(a, b);
}
