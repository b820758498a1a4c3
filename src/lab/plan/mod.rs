//! Planning sequences of scoops and strokes (seed B §2.2, its Algorithm 1): an A* search whose
//! expansion optimises the next action from a node's contact (`OptWrench`) and relocates the
//! contact when that fails, or by chance (`ContactLoc`) ([`search`]); where to put a spoon into
//! a cup's powder next ([`contact`]); the two tasks, multi-scoop dosing ([`dosing`]) and pushing
//! or pulling powder with a spatula ([`push`]); their rollouts' [`journal`] and what
//! `powderlab plan` writes ([`output`]).

pub mod contact;
pub mod dosing;
pub mod journal;
pub mod output;
pub mod push;
pub mod search;
pub mod stroke;
pub(crate) mod study;

use serde::{Deserialize, Serialize};

/// Which planner.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// A* over optimised actions (seed B's Algorithm 1).
    Astar,
    /// One optimised action after another from the best contact, no search.
    Greedy,
    /// A fixed action repeated: the scene's scoop at the highest entry, or a straight stroke
    /// through the powder still outside.
    Scripted,
}

impl Method {
    pub fn name(self) -> &'static str {
        match self {
            Method::Astar => "astar",
            Method::Greedy => "greedy",
            Method::Scripted => "scripted",
        }
    }
    pub fn parse(s: &str) -> Option<Method> {
        [Method::Astar, Method::Greedy, Method::Scripted]
            .into_iter()
            .find(|m| m.name() == s)
    }
}
