//! Monte Carlo random walks in a unit sphere of homogeneous medium.
//!
//! This crate is the single source of truth for the physics conventions of stcvae
//! (design brief §2): the Henyey–Greenstein phase function, free flights, the
//! unit-sphere walk that starts with a scattering event at the centre, the canonical
//! frame in which walks are recorded, the choice of the representative event for
//! next-event estimation, and the parameter ranges. The training code and the
//! renderers call these functions rather than re-deriving them.

pub mod conditions;
pub mod dataset;
pub mod frame;
pub mod output;
pub mod phase;
pub mod quiet;
pub mod ranges;
pub mod reservoir;
pub mod rng;
pub mod stats;
pub mod walk;

pub use conditions::{ConditionSampler, Conditions};
pub use frame::{CanonicalExit, WalkFrame};
pub use rng::WalkRng;
pub use walk::{CanonicalWalk, Walk, WalkEnd, simulate_walk, walk_with};
