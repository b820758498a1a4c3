//! A* over optimised actions (seed B's Algorithm 1).
//!
//! A node is whatever a task needs (for dosing: the powder's state, the mass delivered and the
//! spoon's entry point). Expanding a node `s`:
//!
//! 1. `OptWrench(s)` optimises the next action from `s`'s contact, giving `s'` and its cost;
//! 2. if `OptIsSuccess(s, s')`, `s'` joins the frontier;
//! 3. otherwise `ContactLoc(s)` proposes `s` with new contacts, and they join it;
//! 4. with probability `explore`, `s`'s relocations join it even when the action succeeded
//!    (seed B's random contact transition, which keeps the search from pruning paths that
//!    switch contact early).
//!
//! A node that a relocation made is not relocated again, neither by chance nor when its action
//! fails: its parent's `ContactLoc` already offered every alternative, two moves in a row cost
//! more than the second alone, and without the rule a state where no contact works fills the
//! tree with moves (a blind search of the test's mock did not finish in 10,000 expansions).
//!
//! The frontier is ordered by `f = g + h` with `h` the task's heuristic; a node is a success
//! when it is *taken* from the frontier, not when it is made, so with an admissible `h` (never
//! above the cost still to pay) the first success is a cheapest one among the nodes the
//! expansions can reach. Ties in `f` go to the node made first, so a search is deterministic
//! given its seed.

use crate::util::SplitMix64;
use std::cmp::Ordering;
use std::collections::BinaryHeap;

/// What a task gives the search.
pub trait Task {
    type Node: Clone;
    /// `IsSuccess`: the goal is reached at `n`.
    fn is_success(&self, n: &Self::Node) -> bool;
    /// `OptWrench`: the next action optimised from `n`'s contact, as the node it leads to and
    /// its cost (scoops, strokes or seconds); `None` when no action could be run.
    fn opt_wrench(&mut self, n: &Self::Node) -> anyhow::Result<Option<(Self::Node, f64)>>;
    /// `OptIsSuccess`: the action from `from` to `to` did what it aimed for.
    fn opt_is_success(&self, from: &Self::Node, to: &Self::Node) -> bool;
    /// `ContactLoc`: `n` with its contact moved, each with the move's cost.
    fn contact_loc(&mut self, n: &Self::Node) -> Vec<(Self::Node, f64)>;
    /// A lower bound on the cost from `n` to a success (0 is always admissible).
    fn heuristic(&self, n: &Self::Node) -> f64;
    /// How far `n` is from the goal, for the plan a search without success returns (the
    /// node made with the smallest; ties to the first made). Default: the heuristic, which
    /// is often too coarse (a dosing task's counts scoops, its distance counts grams).
    fn distance(&self, n: &Self::Node) -> f64 {
        self.heuristic(n)
    }
}

/// How the search runs.
#[derive(Clone, Debug)]
pub struct SearchOptions {
    /// The chance that a node's contact is also relocated after a successful action.
    pub explore: f64,
    pub seed: u64,
    /// Nodes expanded at most before the search gives up.
    pub max_expansions: usize,
}

/// What a search gives.
#[derive(Clone, Debug)]
pub struct SearchResult<N> {
    /// From the start to a success, or (when none was found) to the node of smallest
    /// [`Task::distance`] made.
    pub path: Vec<N>,
    pub cost: f64,
    pub success: bool,
    /// Nodes taken from the frontier and expanded.
    pub expansions: usize,
}

/// A frontier entry: its `f`, the order it was made in, and its index in the arena.
struct Entry {
    f: f64,
    order: usize,
    index: usize,
}

impl PartialEq for Entry {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}
impl Eq for Entry {}
impl PartialOrd for Entry {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Entry {
    /// The heap's greatest is the lowest `f`, then the earliest made.
    fn cmp(&self, other: &Self) -> Ordering {
        other
            .f
            .total_cmp(&self.f)
            .then_with(|| other.order.cmp(&self.order))
    }
}

/// Runs the search from `start`.
pub fn search<T: Task>(
    task: &mut T,
    start: T::Node,
    opts: &SearchOptions,
) -> anyhow::Result<SearchResult<T::Node>> {
    anyhow::ensure!(
        (0.0..=1.0).contains(&opts.explore),
        "explore {}: expected a chance in [0, 1]",
        opts.explore
    );
    let mut rng = SplitMix64(opts.seed);
    // The arena: each node, its parent, its cost so far and whether a relocation made it.
    let mut arena: Vec<(T::Node, Option<usize>, f64, bool)> = Vec::new();
    let mut frontier = BinaryHeap::new();
    let push = |arena: &mut Vec<(T::Node, Option<usize>, f64, bool)>,
                frontier: &mut BinaryHeap<Entry>,
                f: f64,
                entry: (T::Node, Option<usize>, f64, bool)| {
        arena.push(entry);
        let index = arena.len() - 1;
        frontier.push(Entry {
            f,
            order: index,
            index,
        });
    };
    let h0 = task.heuristic(&start);
    push(&mut arena, &mut frontier, h0, (start, None, 0.0, false));
    let path_to = |arena: &Vec<(T::Node, Option<usize>, f64, bool)>, mut i: usize| {
        let mut path = vec![arena[i].0.clone()];
        while let Some(p) = arena[i].1 {
            path.push(arena[p].0.clone());
            i = p;
        }
        path.reverse();
        path
    };
    let mut expansions = 0;
    while let Some(Entry { index, .. }) = frontier.pop() {
        let (node, _, g, moved) = arena[index].clone();
        if task.is_success(&node) {
            return Ok(SearchResult {
                path: path_to(&arena, index),
                cost: g,
                success: true,
                expansions,
            });
        }
        if expansions == opts.max_expansions {
            break;
        }
        expansions += 1;
        let acted = match task.opt_wrench(&node)? {
            Some((next, cost)) if task.opt_is_success(&node, &next) => {
                let f = g + cost + task.heuristic(&next);
                push(
                    &mut arena,
                    &mut frontier,
                    f,
                    (next, Some(index), g + cost, false),
                );
                true
            }
            _ => false,
        };
        // The draw is made for every node, so the sequence of draws does not depend on which
        // nodes were relocations.
        let chance = rng.uniform() < opts.explore;
        if (!acted || chance) && !moved {
            for (to, cost) in task.contact_loc(&node) {
                let f = g + cost + task.heuristic(&to);
                push(
                    &mut arena,
                    &mut frontier,
                    f,
                    (to, Some(index), g + cost, true),
                );
            }
        }
    }
    let mut closest = 0;
    for (i, n) in arena.iter().enumerate() {
        if task.distance(&n.0) < task.distance(&arena[closest].0) {
            closest = i;
        }
    }
    Ok(SearchResult {
        path: path_to(&arena, closest),
        cost: arena[closest].2,
        success: false,
        expansions,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A mock dosing task: grams still to deliver, the entry point, and how often each entry
    /// point has been scooped. A scoop at entry `e` the `k`-th time delivers `yields[e][k]` g
    /// (its crater yields less each time, 0 when spent); it succeeds when it delivers something
    /// without passing the target. Moving the spoon costs `move_cost`, a scoop 1.
    #[derive(Clone, Debug, PartialEq)]
    struct Node {
        left: u32,
        entry: usize,
        scoops: Vec<usize>,
        /// The cost paid to reach it (the mock keeps it to check what A* expands).
        spent: f64,
    }

    struct Dosing {
        yields: Vec<Vec<u32>>,
        move_cost: f64,
        /// The heuristic's divisor: the largest yield (admissible), or 0 for none.
        capacity: u32,
        expanded: Vec<Node>,
    }

    impl Dosing {
        fn new(capacity: u32) -> Dosing {
            Dosing {
                // Entry 0 is generous at first and soon spent; entry 2 is steady.
                yields: vec![vec![5, 4, 1], vec![3, 3, 3, 3], vec![4, 4, 4, 4]],
                move_cost: 0.25,
                capacity,
                expanded: Vec::new(),
            }
        }
        fn scoop(&self, n: &Node) -> u32 {
            self.yields[n.entry]
                .get(n.scoops[n.entry])
                .copied()
                .unwrap_or(0)
        }
    }

    impl Task for Dosing {
        type Node = Node;
        fn is_success(&self, n: &Node) -> bool {
            n.left == 0
        }
        fn opt_wrench(&mut self, n: &Node) -> anyhow::Result<Option<(Node, f64)>> {
            self.expanded.push(n.clone());
            let got = self.scoop(n);
            let mut m = n.clone();
            m.left = n.left.saturating_sub(got);
            m.scoops[n.entry] += 1;
            m.spent += 1.0;
            Ok(Some((m, 1.0)))
        }
        fn opt_is_success(&self, from: &Node, to: &Node) -> bool {
            let got = from.left - to.left;
            got > 0 && self.scoop(from) <= from.left
        }
        fn contact_loc(&mut self, n: &Node) -> Vec<(Node, f64)> {
            (0..self.yields.len())
                .filter(|&e| e != n.entry)
                .map(|e| {
                    (
                        Node {
                            entry: e,
                            spent: n.spent + self.move_cost,
                            ..n.clone()
                        },
                        self.move_cost,
                    )
                })
                .collect()
        }
        fn heuristic(&self, n: &Node) -> f64 {
            if self.capacity == 0 {
                0.0
            } else {
                n.left.div_ceil(self.capacity) as f64
            }
        }
    }

    /// The cheapest cost to deliver `left` exactly from `n`, by exhaustive search.
    fn brute_force(t: &Dosing, n: &Node, depth: usize) -> f64 {
        if n.left == 0 {
            return 0.0;
        }
        if depth == 0 {
            return f64::INFINITY;
        }
        let mut best = f64::INFINITY;
        for e in 0..t.yields.len() {
            let mut m = Node {
                entry: e,
                ..n.clone()
            };
            let moved = if e == n.entry { 0.0 } else { t.move_cost };
            let got = t.scoop(&m);
            if got == 0 || got > m.left {
                continue;
            }
            m.left -= got;
            m.scoops[e] += 1;
            best = best.min(moved + 1.0 + brute_force(t, &m, depth - 1));
        }
        best
    }

    fn start(left: u32) -> Node {
        Node {
            left,
            entry: 0,
            scoops: vec![0; 3],
            spent: 0.0,
        }
    }

    const OPTS: SearchOptions = SearchOptions {
        explore: 0.0,
        seed: 1,
        max_expansions: 10_000,
    };

    #[test]
    fn finds_the_cheapest_sequence() {
        for target in [9, 12, 15, 20] {
            let mut t = Dosing::new(5);
            let best = brute_force(&t, &start(target), 8);
            // Without exploration a successful scoop is never followed by a move, which can
            // prune the cheapest sequence; with it every node also relocates.
            let r = search(
                &mut t,
                start(target),
                &SearchOptions {
                    explore: 1.0,
                    ..OPTS
                },
            )
            .unwrap();
            assert!(r.success, "{target} g");
            assert!(
                (r.cost - best).abs() < 1e-12,
                "{target} g: A* {} against the cheapest {best}",
                r.cost
            );
            assert_eq!(r.path.last().unwrap().left, 0);
            assert_eq!(r.path.first().unwrap(), &start(target));
        }
    }

    /// With a consistent heuristic (a scoop of at most 5 g costs 1 and lowers ⌈left/5⌉ by at
    /// most 1; a move changes neither) A* expands no node whose `g + h` is above the optimum,
    /// and fewer nodes than without a heuristic.
    #[test]
    fn honours_the_heuristic() {
        let full = SearchOptions {
            explore: 1.0,
            ..OPTS
        };
        let mut with = Dosing::new(5);
        let r = search(&mut with, start(12), &full).unwrap();
        let mut blind = Dosing::new(0);
        let b = search(&mut blind, start(12), &full).unwrap();
        assert!(r.success && b.success);
        assert_eq!(r.cost, b.cost);
        assert!(
            r.expansions < b.expansions,
            "{} expansions with the heuristic, {} without",
            r.expansions,
            b.expansions
        );
        for n in &with.expanded {
            let f = n.spent + with.heuristic(n);
            assert!(
                f <= r.cost + 1e-12,
                "expanded {n:?} at f = {f} > {}",
                r.cost
            );
        }
    }

    #[test]
    fn gives_the_closest_node_when_the_budget_runs_out() {
        let mut t = Dosing::new(5);
        let r = search(
            &mut t,
            start(40),
            &SearchOptions {
                max_expansions: 3,
                ..OPTS
            },
        )
        .unwrap();
        assert!(!r.success);
        assert_eq!(r.expansions, 3);
        assert!(r.path.last().unwrap().left < 40);
        assert!(search(
            &mut t,
            start(5),
            &SearchOptions {
                explore: 1.5,
                ..OPTS
            }
        )
        .is_err());
    }
}
