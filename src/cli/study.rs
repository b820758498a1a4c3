//! `powderlab study NAME`: the studies behind `docs/results/`, one subcommand each with its own
//! arguments, from the lab's one table ([`powderlab::lab::study::table::STUDIES`]).

use anyhow::Result;
use clap::{ArgMatches, Command, FromArgMatches};

/// The `study` command's matches, parsed by the table's subcommands.
pub struct Args {
    matches: ArgMatches,
}

impl FromArgMatches for Args {
    fn from_arg_matches(m: &ArgMatches) -> Result<Self, clap::Error> {
        Ok(Args { matches: m.clone() })
    }

    fn update_from_arg_matches(&mut self, m: &ArgMatches) -> Result<(), clap::Error> {
        self.matches = m.clone();
        Ok(())
    }
}

impl clap::Args for Args {
    fn augment_args(cmd: Command) -> Command {
        powderlab::lab::study::table::command(cmd)
    }

    fn augment_args_for_update(cmd: Command) -> Command {
        Self::augment_args(cmd)
    }
}

/// Runs the study the arguments name.
pub fn run(a: Args) -> Result<()> {
    powderlab::lab::study::table::dispatch(&a.matches)
}
