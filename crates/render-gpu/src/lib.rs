//! The renderers of stcvae. Filled in by the rendering issues; empty until then.
