//! Training with burn (feature `train`).

pub mod adamax;
pub mod data;
pub mod network;
pub mod trainer;
pub mod validation;

pub use data::{ModelKind, Table};
pub use trainer::{ModelConfig, TrainError, Trained, train_model};
