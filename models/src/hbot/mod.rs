//! H-Bot belt drive: kinematics, step generation, dynamics twin, identification, compensation.
