//! Planning sequences of scoops and strokes (seed B §2.2, its Algorithm 1): an A* search whose
//! expansion optimises the next action from a node's contact (`OptWrench`) and relocates the
//! contact when that fails, or by chance (`ContactLoc`) ([`search`]); where to put a spoon into
//! a cup's powder next ([`contact`]).

pub mod contact;
pub mod dosing;
pub mod journal;
pub mod output;
pub mod push;
pub mod search;
