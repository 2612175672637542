//! The offline subcommands: planning seeded or given instances in-process
//! (`solve`, `bench`, `eval`) and what they share (instances, methods,
//! statistics).

pub mod bench;
pub mod eval;
pub mod instances;
pub mod methods;
pub mod solve;
pub mod stats;
