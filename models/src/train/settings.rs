//! The settings of both trainings and what a finished one reports.

use serde::{Deserialize, Serialize};

/// Optimisation settings shared by both trainings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainConfig {
    /// Optimiser steps.
    pub steps: usize,
    /// Robot tokens per batch (batch size = this / team size).
    pub tokens_per_batch: usize,
    /// Peak learning rate (AdamW, no weight decay).
    pub lr: f64,
    /// Final learning rate of the cosine schedule.
    pub lr_min: f64,
    /// Linear warm-up steps.
    pub warmup: usize,
    /// Global gradient-norm clip.
    pub clip: f64,
    /// Seed of the initial weights, batches, noise and times.
    pub seed: u64,
    /// Fraction of every bucket held out for validation.
    pub validation_fraction: f64,
    /// Steps between validations (and checkpoints).
    pub checkpoint_every: usize,
}

impl TrainConfig {
    /// Learning rate at `step`.
    pub fn lr_at(&self, step: usize) -> f64 {
        if step < self.warmup {
            return self.lr * (step + 1) as f64 / self.warmup as f64;
        }
        let progress = (step - self.warmup) as f64 / (self.steps - self.warmup).max(1) as f64;
        self.lr_min + 0.5 * (self.lr - self.lr_min) * (1.0 + (std::f64::consts::PI * progress.min(1.0)).cos())
    }
}

/// What a finished training reports (the model card's metrics).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TrainReport {
    /// Steps run in this process (after any resumed checkpoint).
    pub steps_run: usize,
    /// Mean training loss over the last validation interval.
    pub final_train_loss: f64,
    /// Validation loss at the first and last validation.
    pub first_validation_loss: f64,
    /// Validation loss at the end.
    pub validation_loss: f64,
    /// Wall time of this process's training (s).
    pub wall_s: f64,
}
