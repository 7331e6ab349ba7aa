//! Training with burn (feature `train`).

pub mod adamax;
pub mod checkpoint;
pub mod config;
pub mod data;
pub mod network;
pub mod trainer;
pub mod validation;

pub use config::ModelConfig;
pub use data::{ModelKind, Table};
pub use trainer::{TrainError, Trained, train_model};
