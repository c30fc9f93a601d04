//! PLACEHOLDER (disc-domains): disc-core owns this file; only the domain lines below are ours.

pub mod select;

pub mod extrusion;
pub mod motion;
pub mod simfit;
