//! The learning subcommands: training data and training (`datagen`,
//! `train`).

pub mod datagen;
pub mod train;
