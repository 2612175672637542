//! Training loops: seeded, checkpointed, validated, ending in a weight file
//! ([`crate::weights`]) and a model card beside it.
//!
//! Batches come from one (team size, obstacle count) bucket at a time, so
//! every tensor in a batch has one shape (no padding or masks); buckets are
//! drawn in proportion to their size and batches hold about
//! `tokens_per_batch` robot tokens. The last `validation_fraction` of every
//! bucket is held out. A checkpoint (weights and step) is written every
//! `checkpoint_every` steps; a restarted run resumes from it with fresh
//! optimiser moments.

mod card;
mod data;
mod initialiser;
mod policy;
mod run;
mod settings;

pub use card::ModelCard;
pub use data::statistics;
pub use initialiser::{InitData, train_init};
pub use policy::{FlowStart, train_flow};
pub use settings::{TrainConfig, TrainReport};
