//! The CVAE models of stcvae. Filled in by the training issue; empty until then.
