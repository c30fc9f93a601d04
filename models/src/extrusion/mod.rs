//! Extrusion: linear pressure model (pressure advance) and the calibration twin.
