//! Firmware export text for identified hotend models and designed controllers.
//!
//! Units, checked against the firmware sources:
//! - Marlin `M306` (MPC, Marlin ≥ 2.1): `P` heater power W, `C` block heat
//!   capacity J/K, `R` sensor responsiveness K/s/K, `A` ambient transfer
//!   W/K (fan off), `F` ambient transfer W/K with the fan at full, `H`
//!   filament heat capacity J/K/mm.
//! - Marlin `M301` and Klipper `pid_Kp/Ki/Kd`: gains on a 0..255 output scale
//!   (Klipper divides by `PID_PARAM_BASE = 255`), `I` per second, `D` in seconds.
//! - Klipper MPC (Kalico / Danger-Klipper `control: mpc`): the same physics as
//!   Marlin's with `fan_ambient_transfer` as a list over equally spaced fan speeds.
//! - RepRapFirmware `M307` (3.3+): `R` heating rate °C/s at full power, `K`
//!   cooling rate °C/s at 100 °C above ambient, fan off `:` extra with the fan
//!   at full, `D` dead time s, `E` cooling exponent, `S` max PWM.

use crate::DatasetError;
use fdmlab_models::thermal::control::{Pid, Placement};
use fdmlab_models::thermal::physics::Rates;

/// Export formats: the one list, read by clap (`export thermal --format`,
/// with the `clap` feature) and written by the `thermal-grid` kind ([`Format::ALL`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Format {
    /// `M306` MPC line.
    MarlinMpc,
    /// `M301` PID line.
    MarlinPid,
    /// `[extruder]` PID block.
    KlipperPid,
    /// `[extruder]` MPC block (Kalico / Danger-Klipper).
    KlipperMpc,
    /// `M307` heater model.
    Reprap,
    /// C header with L and M.
    CHeader,
}

impl Format {
    /// Every format, in the order the `thermal-grid` kind writes them.
    pub const ALL: [Format; 6] = [Format::MarlinMpc, Format::KlipperMpc, Format::Reprap, Format::MarlinPid, Format::KlipperPid, Format::CHeader];

    /// File name of the format's artifact (the `thermal-grid` kind's `export` stage).
    pub fn file_name(self) -> &'static str {
        match self {
            Format::MarlinMpc => "marlin-mpc.gcode",
            Format::KlipperMpc => "klipper-mpc.cfg",
            Format::Reprap => "reprap.g",
            Format::MarlinPid => "marlin-pid.gcode",
            Format::KlipperPid => "klipper-pid.cfg",
            Format::CHeader => "thermal_gains.h",
        }
    }

    /// Media type of the artifact.
    pub fn media_type(self) -> &'static str {
        match self {
            Format::CHeader => "text/x-c",
            _ => "text/plain",
        }
    }

    /// Whether the format is made from a grey-box model's physical rates
    /// (Marlin/Klipper MPC, RepRap `M307`) rather than from a controller design.
    pub fn needs_physics(self) -> bool {
        matches!(self, Format::MarlinMpc | Format::KlipperMpc | Format::Reprap)
    }
}

/// What the formats are made from. [`export`] asks only for what the chosen
/// format needs, so a caller computes (and fails on) nothing else: the CLI
/// designs lazily from a model file, the `thermal-grid` kind hands over its
/// stored designs.
pub trait Design {
    /// The caller's error (a refused export converts into it).
    type Error: From<DatasetError>;
    /// The grey-box model's identified rates (MPC, `M307`).
    fn rates(&self) -> Result<Rates, Self::Error>;
    /// Heater power, W, and filament heat capacity, J/K per mm (MPC).
    fn mpc_inputs(&self) -> Result<(f64, f64), Self::Error>;
    /// Dead time of the heater's FOPDT approximation, s (`M307 D`).
    fn dead_time_s(&self) -> Result<f64, Self::Error>;
    /// PID gains (`M301`, Klipper PID).
    fn pid(&self) -> Result<Pid, Self::Error>;
    /// State-feedback placement and the model name the header states.
    fn placement(&self) -> Result<(Placement, String), Self::Error>;
}

/// The one thermal export dispatcher (as `pa::export::export` for K_A):
/// `format`'s text from `design`, with `note` as its comment line.
pub fn export<D: Design>(format: Format, design: &D, note: &str) -> Result<String, D::Error> {
    let mpc = || -> Result<MpcPhysics, D::Error> {
        let rates = design.rates()?;
        let (power_w, filament_j_k_mm) = design.mpc_inputs()?;
        Ok(mpc_physics_from_rates(&rates, power_w, filament_j_k_mm)?)
    };
    Ok(match format {
        Format::MarlinMpc => marlin_mpc(&mpc()?, note)?,
        Format::KlipperMpc => klipper_mpc(&mpc()?, note)?,
        Format::Reprap => {
            let rates = design.rates()?;
            reprap(&rates, design.dead_time_s()?, note)?
        }
        Format::MarlinPid => marlin_pid(&design.pid()?, note)?,
        Format::KlipperPid => klipper_pid(&design.pid()?, note)?,
        Format::CHeader => {
            let (placement, model) = design.placement()?;
            c_header(&placement, &model)?
        }
    })
}

/// Physical parameters in firmware units, from identified rates and the
/// heater power stated by the user (a temperature log alone only gives P/C).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct MpcPhysics {
    /// Heater power, W.
    pub heater_power_w: f64,
    /// Block heat capacity, J/K.
    pub block_heat_capacity_j_k: f64,
    /// Sensor responsiveness, K/s/K (1/τ).
    pub sensor_responsiveness: f64,
    /// Ambient transfer, fan off, W/K.
    pub ambient_transfer_w_k: f64,
    /// Ambient transfer, fan at full, W/K.
    pub fan_ambient_transfer_w_k: f64,
    /// Filament heat capacity per mm, J/K/mm.
    pub filament_heat_capacity_j_k_mm: f64,
}

/// Convert identified rates to firmware physics: `C = P / r`, transfers = rate·C.
pub fn mpc_physics_from_rates(rates: &Rates, heater_power_w: f64, filament_heat_capacity_j_k_mm: f64) -> Result<MpcPhysics, DatasetError> {
    if !(heater_power_w.is_finite() && heater_power_w > 0.0 && heater_power_w <= 1000.0) {
        return Err(DatasetError::Refused(format!("heater power {heater_power_w} W must be within 0..1000 W")));
    }
    if !(filament_heat_capacity_j_k_mm.is_finite() && (0.0..=1.0).contains(&filament_heat_capacity_j_k_mm)) {
        return Err(DatasetError::Refused(format!("filament heat capacity {filament_heat_capacity_j_k_mm} J/(K·mm) must be within 0..1")));
    }
    if !(rates.is_physical() && rates.heat_k_s > 0.0) {
        return Err(DatasetError::Refused(format!("identified rates are not physical: {rates:?}")));
    }
    let c = heater_power_w / rates.heat_k_s;
    Ok(MpcPhysics {
        heater_power_w,
        block_heat_capacity_j_k: c,
        sensor_responsiveness: 1.0 / rates.sensor_tau_s,
        ambient_transfer_w_k: rates.loss_1_s * c,
        fan_ambient_transfer_w_k: (rates.loss_1_s + rates.fan_loss_1_s) * c,
        filament_heat_capacity_j_k_mm,
    })
}

fn finite(values: &[(&str, f64)]) -> Result<(), DatasetError> {
    match values.iter().find(|(_, v)| !v.is_finite()) {
        Some((n, v)) => Err(DatasetError::Refused(format!("{n} = {v} is not finite; nothing exported"))),
        None => Ok(()),
    }
}

/// `M306 P… C… R… A… F… H…`.
pub fn marlin_mpc(p: &MpcPhysics, note: &str) -> Result<String, DatasetError> {
    finite(&[
        ("P", p.heater_power_w),
        ("C", p.block_heat_capacity_j_k),
        ("R", p.sensor_responsiveness),
        ("A", p.ambient_transfer_w_k),
        ("F", p.fan_ambient_transfer_w_k),
        ("H", p.filament_heat_capacity_j_k_mm),
    ])?;
    Ok(format!(
        "; {note}\nM306 E0 P{:.2} C{:.4} R{:.6} A{:.6} F{:.6} H{:.6}\nM500 ; save to EEPROM\n",
        p.heater_power_w,
        p.block_heat_capacity_j_k,
        p.sensor_responsiveness,
        p.ambient_transfer_w_k,
        p.fan_ambient_transfer_w_k,
        p.filament_heat_capacity_j_k_mm
    ))
}

fn pid_255(pid: &Pid) -> Result<(f64, f64, f64), DatasetError> {
    finite(&[("Kp", pid.kp), ("Ki", pid.ki), ("Kd", pid.kd)])?;
    if pid.kp < 0.0 || pid.ki < 0.0 || pid.kd < 0.0 {
        return Err(DatasetError::Refused(format!("negative PID gain {pid:?}; nothing exported")));
    }
    Ok((pid.kp * 255.0, pid.ki * 255.0, pid.kd * 255.0))
}

/// `M301 P… I… D…` (gains on Marlin's 0..255 scale).
pub fn marlin_pid(pid: &Pid, note: &str) -> Result<String, DatasetError> {
    let (p, i, d) = pid_255(pid)?;
    Ok(format!("; {note} ({})\nM301 E0 P{p:.4} I{i:.4} D{d:.4}\nM500 ; save to EEPROM\n", pid.rule))
}

/// `[extruder]` PID block (Klipper units: gains × 255).
pub fn klipper_pid(pid: &Pid, note: &str) -> Result<String, DatasetError> {
    let (p, i, d) = pid_255(pid)?;
    Ok(format!("# {note} ({})\n[extruder]\ncontrol: pid\npid_Kp: {p:.3}\npid_Ki: {i:.3}\npid_Kd: {d:.3}\n", pid.rule))
}

/// Filament diameter written in the Kalico MPC block, mm.
pub const KALICO_FILAMENT_DIAMETER_MM: f64 = 1.75;
/// Filament density written in the Kalico MPC block, g/cm³.
pub const KALICO_FILAMENT_DENSITY_G_CM3: f64 = 1.25;

/// `[extruder]` MPC block; fan transfer listed at 0, 25, 50, 75, 100 % fan;
/// filament diameter, density and heat capacity whose product is Marlin's `H`.
pub fn klipper_mpc(p: &MpcPhysics, note: &str) -> Result<String, DatasetError> {
    finite(&[("heater_power", p.heater_power_w), ("block_heat_capacity", p.block_heat_capacity_j_k), ("sensor_responsiveness", p.sensor_responsiveness)])?;
    let fan: Vec<String> =
        (0..5).map(|i| format!("{:.6}", p.ambient_transfer_w_k + (p.fan_ambient_transfer_w_k - p.ambient_transfer_w_k) * i as f64 / 4.0)).collect();
    // Kalico's filament feed-forward uses only the product
    // π(d/2)²/1000 · filament_density [g/cm³] · filament_heat_capacity [J/g/K] (J/K per mm,
    // `klippy/extras/control_mpc.py` `_update_filament_const`): Marlin's H. fdmlab writes
    // d = 1.75 mm and ρ = 1.25 g/cm³ (Kalico's PLA row, docs/MPC.md) and the c that makes
    // the product H; Kalico multiplies it by the E axis velocity (mm of filament) whatever
    // the real diameter.
    let (d, rho) = (KALICO_FILAMENT_DIAMETER_MM, KALICO_FILAMENT_DENSITY_G_CM3);
    let c = p.filament_heat_capacity_j_k_mm * 1000.0 / (std::f64::consts::PI * (d / 2.0).powi(2) * rho);
    Ok(format!(
        "# {note}\n# Kalico / Danger-Klipper MPC (mainline Klipper has no MPC)\n[extruder]\ncontrol: mpc\nheater_power: {:.2}\ncooling_fan: fan\nblock_heat_capacity: {:.4}\nsensor_responsiveness: {:.6}\nambient_transfer: {:.6}\nfan_ambient_transfer: {}\nfilament_diameter: {d}\nfilament_density: {rho}\nfilament_heat_capacity: {c:.6}\n",
        p.heater_power_w,
        p.block_heat_capacity_j_k,
        p.sensor_responsiveness,
        p.ambient_transfer_w_k,
        fan.join(", ")
    ))
}

/// `M307 H1 R… K…:… D… E1.00 S1.00 B0` from identified rates (linear cooling, E = 1).
pub fn reprap(rates: &Rates, dead_time_s: f64, note: &str) -> Result<String, DatasetError> {
    let r = rates.heat_k_s;
    let k = rates.loss_1_s * 100.0;
    let kf = rates.fan_loss_1_s * 100.0;
    finite(&[("R", r), ("K", k), ("K fan", kf), ("D", dead_time_s)])?;
    if dead_time_s < 0.0 {
        return Err(DatasetError::Refused(format!("dead time {dead_time_s} s is negative")));
    }
    Ok(format!("; {note}\nM307 H1 R{r:.3} K{k:.3}:{kf:.3} D{dead_time_s:.2} E1.00 S1.00 B0\n"))
}

/// C header with the state-feedback gains.
pub fn c_header(p: &Placement, model: &str) -> Result<String, DatasetError> {
    finite(&[("M", p.m)])?;
    for (i, v) in p.l.iter().enumerate() {
        finite(&[(&format!("L[{i}]"), *v)])?;
    }
    let l: Vec<String> = p.l.iter().map(|v| format!("{v:e}")).collect();
    let poles: Vec<String> = p.requested_poles.iter().map(|z| if z[1] == 0.0 { format!("{}", z[0]) } else { format!("{}{:+}i", z[0], z[1]) }).collect();
    Ok(format!(
        "/* Generated by fdmlab: state feedback u = -L x + M r for model {model}.\n * Poles: {} ({}, {:?} placement). */\n#ifndef FDMLAB_THERMAL_GAINS_H\n#define FDMLAB_THERMAL_GAINS_H\n\n#define FDMLAB_THERMAL_STATES {}\nstatic const double fdmlab_thermal_L[FDMLAB_THERMAL_STATES] = {{ {} }};\nstatic const double fdmlab_thermal_M = {:e};\nstatic const double fdmlab_thermal_dt_s = {:e}; /* 0: continuous-time design */\n\n#endif /* FDMLAB_THERMAL_GAINS_H */\n",
        poles.join(", "),
        if p.dt_s.is_some() { "z-plane" } else { "s-plane" },
        p.method,
        p.l.len(),
        l.join(", "),
        p.m,
        p.dt_s.unwrap_or(0.0)
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use fdmlab_models::thermal::control::PlacementMethod;

    fn rates() -> Rates {
        Rates {
            heat_k_s: 0.5,
            loss_1_s: 0.002,
            fan_loss_1_s: 0.00125,
            near_loss_1_s: 0.0,
            near_scale: 15.0,
            sensor_tau_s: 8.0,
            extrude_loss_1_s_per_mm3_s: 0.0,
        }
    }

    #[test]
    fn mpc_physics_match_the_twin() {
        // Twin: P = 20 W, C = 40 J/K, g0 = 0.08 W/K, g_fan = 0.05 W/K, τs = 8 s.
        let p = mpc_physics_from_rates(&rates(), 20.0, 0.0056).expect("physics");
        assert!((p.block_heat_capacity_j_k - 40.0).abs() < 1e-9);
        assert!((p.ambient_transfer_w_k - 0.08).abs() < 1e-12 && (p.fan_ambient_transfer_w_k - 0.13).abs() < 1e-12);
        let m306 = marlin_mpc(&p, "twin").expect("m306");
        assert!(m306.contains("M306 E0 P20.00 C40.0000 R0.125000 A0.080000 F0.130000 H0.005600"), "{m306}");
        let k = klipper_mpc(&p, "twin").expect("klipper");
        assert!(k.contains("fan_ambient_transfer: 0.080000, 0.092500, 0.105000, 0.117500, 0.130000"), "{k}");
        // Kalico's `_update_filament_const` on the written values gives M306's H (J/K per mm).
        let val = |key: &str| k.lines().find_map(|l| l.strip_prefix(key)).and_then(|v| v.trim().parse::<f64>().ok()).expect(key);
        let (d, rho, c) = (val("filament_diameter:"), val("filament_density:"), val("filament_heat_capacity:"));
        let h = (d / 2.0) * (d / 2.0) * std::f64::consts::PI / 1000.0 * rho * c;
        assert!((h - 0.0056).abs() < 1e-8, "{h}");
        assert!(mpc_physics_from_rates(&rates(), -1.0, 0.0).is_err());
    }

    #[test]
    fn pid_gains_are_scaled_to_255() {
        let pid = Pid { kp: 0.1, ki: 0.001, kd: 0.5, rule: "test".into() };
        assert!(marlin_pid(&pid, "n").expect("m301").contains("M301 E0 P25.5000 I0.2550 D127.5000"));
        assert!(klipper_pid(&pid, "n").expect("k").contains("pid_Kp: 25.500\npid_Ki: 0.255\npid_Kd: 127.500"));
        assert!(marlin_pid(&Pid { kp: f64::NAN, ..pid.clone() }, "n").is_err());
    }

    #[test]
    fn reprap_and_c_header() {
        assert!(reprap(&rates(), 6.5, "n").expect("m307").contains("M307 H1 R0.500 K0.200:0.125 D6.50 E1.00 S1.00 B0"));
        let p = Placement {
            l: vec![1.5, -2.0],
            m: 0.25,
            closed_loop_poles: vec![],
            requested_poles: vec![[-0.1, 0.0], [-0.1, 0.0]],
            method: PlacementMethod::Ackermann,
            dt_s: None,
            controllability_condition: 1.0,
        };
        let h = c_header(&p, "greybox-2").expect("header");
        assert!(h.contains("fdmlab_thermal_L[FDMLAB_THERMAL_STATES] = { 1.5e0, -2e0 };") && h.contains("fdmlab_thermal_M = 2.5e-1;"), "{h}");
    }

    /// A design with PID gains only: asking for anything else fails.
    struct PidOnly(Pid);

    impl Design for PidOnly {
        type Error = DatasetError;
        fn rates(&self) -> Result<Rates, DatasetError> {
            Err(DatasetError::Refused("no grey box".into()))
        }
        fn mpc_inputs(&self) -> Result<(f64, f64), DatasetError> {
            Ok((20.0, 0.0056))
        }
        fn dead_time_s(&self) -> Result<f64, DatasetError> {
            Err(DatasetError::Refused("no plant".into()))
        }
        fn pid(&self) -> Result<Pid, DatasetError> {
            Ok(self.0.clone())
        }
        fn placement(&self) -> Result<(Placement, String), DatasetError> {
            Err(DatasetError::Refused("no placement".into()))
        }
    }

    #[test]
    fn the_dispatcher_asks_only_for_what_a_format_needs() {
        let pid = Pid { kp: 0.1, ki: 0.001, kd: 0.5, rule: "test".into() };
        let d = PidOnly(pid.clone());
        assert_eq!(export(Format::MarlinPid, &d, "n").expect("m301"), marlin_pid(&pid, "n").expect("m301"));
        assert_eq!(export(Format::KlipperPid, &d, "n").expect("klipper"), klipper_pid(&pid, "n").expect("klipper"));
        for f in [Format::MarlinMpc, Format::KlipperMpc, Format::Reprap] {
            assert!(f.needs_physics());
            assert!(export(f, &d, "n").expect_err("no rates").to_string().contains("no grey box"));
        }
        assert!(export(Format::CHeader, &d, "n").expect_err("no placement").to_string().contains("no placement"));
        let names: Vec<&str> = Format::ALL.iter().map(|f| f.file_name()).collect();
        assert_eq!(names, ["marlin-mpc.gcode", "klipper-mpc.cfg", "reprap.g", "marlin-pid.gcode", "klipper-pid.cfg", "thermal_gains.h"]);
    }
}
