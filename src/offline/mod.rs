//! The offline subcommands: planning seeded or given instances in-process
//! (`solve`, `bench`, `eval`) and what they share (instances, the planner's
//! arguments, the measuring harness, statistics).

pub mod bench;
pub mod eval;
pub mod harness;
pub mod instances;
pub mod planning_args;
pub mod solve;
pub mod stats;
