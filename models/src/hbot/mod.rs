//! H-Bot belt drive: kinematics, step generation, dynamics twin, identification, compensation.

pub mod bresenham;
pub mod compensate;
pub mod ident;
pub mod kinematics;
pub mod mixing;
pub mod params;
pub mod profile;
pub mod sensor;
pub mod study;
pub mod twin;

pub use params::{HbotParams, Param, StepperDrive};
pub use twin::{simulate, LinearMove, MotorCommand, Trajectory, Twin};
