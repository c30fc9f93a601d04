//! Adaptive pressure advance (issue #29): K over flow and acceleration.
//!
//! [`twin`] prints the calibration matrix on the extrusion plant with its nonlinear
//! pressure term; [`model`] is the monotone K(flow, acceleration, …) with its
//! uncertainty; [`design`] proposes the next patterns that most reduce that uncertainty
//! over the domain and compares chosen patterns with the grid; [`residual`] checks the
//! model's residuals and sends a line of the twin through the discrepancy workflow.

pub mod design;
pub mod model;
pub mod residual;
pub mod solve;
pub mod twin;
