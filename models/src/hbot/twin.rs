//! The 8-state H-Bot belt-drive twin of Cao, Bi & Zou (2021), eqs. (7)–(10):
//! cart x, bridge y and motor pulley angles φ1, φ2, coupled by the belt springs,
//! with linear-bearing friction `b·v + sign(v)·Fc`, motor resistance
//! `Kt·φ' + sign(φ')·T0` and a stepper drive pulling each rotor to its commanded angle.
//!
//! Integrator: classical RK4 at a fixed step h = `safety / ω_max`, where ω_max is the
//! highest undamped mode of M⁻¹K (belt modes ≈ 770 rad/s with the identified values).
//! The belt modes are lightly damped oscillations, not fast-decaying transients, so
//! the stiffness is oscillatory: RK4's stability interval on the imaginary axis is
//! |ωh| < 2.83 and with the default safety 0.2 it runs 14× inside it with a per-step
//! amplitude error ≈ (ωh)⁶/144 ≈ 4e-7; an implicit BDF would damp those modes
//! artificially and needs Jacobians across the friction discontinuity. The step
//! divides the output period exactly, so samples fall on step boundaries.
//!
//! Stiction: each of the four coordinates has a Coulomb level and is either
//! *stuck* or *slipping* (Karnopp-style explicit switching). At the start of a step
//! a stuck coordinate breaks away when its net non-friction force exceeds the
//! Coulomb level; a slipping one keeps the friction sign it had at the start of the
//! step, so each RK4 step integrates a smooth field. When a slipping velocity
//! changes sign within a step, the coordinate is placed at the interpolated
//! zero-velocity point and sticks. No smoothing constant, no chatter at v = 0.

use super::kinematics::motor_from_cartesian;
use super::params::HbotParams;
use super::profile::MotionProfile;
use crate::ModelError;
use nalgebra::{Matrix4, SymmetricEigen};

/// Default step safety factor ω_max·h (see module doc).
pub const DEFAULT_SAFETY: f64 = 0.2;

/// What the stepper drivers are told: the commanded belt displacements (s1, s2) in metres.
pub trait MotorCommand {
    /// Commanded belt displacements at time `t_s`.
    fn belt_m(&self, t_s: f64) -> [f64; 2];
}

/// A straight move (dx, dy) in metres following a motion profile along its length.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LinearMove {
    pub dx_m: f64,
    pub dy_m: f64,
    pub profile: MotionProfile,
}

impl LinearMove {
    /// A move at constant speed taking `duration_s` (the source's protocol moves).
    pub fn constant_speed(dx_m: f64, dy_m: f64, duration_s: f64) -> Result<Self, ModelError> {
        let profile = MotionProfile::constant_speed(dx_m.hypot(dy_m), duration_s)?;
        Ok(Self { dx_m, dy_m, profile })
    }
    /// Commanded cartesian position (m) at `t_s`.
    pub fn cartesian_m(&self, t_s: f64) -> [f64; 2] {
        let len = self.profile.length;
        if len <= 0.0 {
            return [0.0, 0.0];
        }
        let f = self.profile.position(t_s) / len;
        [self.dx_m * f, self.dy_m * f]
    }
}

impl MotorCommand for LinearMove {
    fn belt_m(&self, t_s: f64) -> [f64; 2] {
        let [x, y] = self.cartesian_m(t_s);
        motor_from_cartesian(x, y)
    }
}

/// Sampled trajectory of the twin (SI units), one entry per output sample.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Trajectory {
    pub t_s: Vec<f64>,
    pub x_m: Vec<f64>,
    pub vx_m_s: Vec<f64>,
    pub y_m: Vec<f64>,
    pub vy_m_s: Vec<f64>,
    pub phi1_rad: Vec<f64>,
    pub omega1_rad_s: Vec<f64>,
    pub phi2_rad: Vec<f64>,
    pub omega2_rad_s: Vec<f64>,
    /// Commanded cartesian position (from the commanded belt displacements).
    pub x_cmd_m: Vec<f64>,
    pub y_cmd_m: Vec<f64>,
    /// Integrator step used (s).
    pub step_s: f64,
}

/// Coulomb state of one coordinate.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Mode {
    Stuck,
    Slipping(f64),
}

/// The twin with its matrices assembled once.
#[derive(Debug, Clone)]
pub struct Twin {
    mass: [f64; 4],
    stiffness: [[f64; 4]; 4],
    viscous: [f64; 4],
    coulomb: [f64; 4],
    r_m: f64,
    drive_k: f64,
    drive_max: f64,
    omega_max: f64,
}

impl Twin {
    /// Assemble M, K and the friction levels from checked parameters.
    /// Stiffness matrix: Cao, Bi & Zou (2021), eqs. (7)–(10), with q = (x, y, φ1, φ2).
    pub fn new(p: &HbotParams) -> Result<Self, ModelError> {
        p.check()?;
        let (kl, kr, ku, r) = (p.k_l_n_per_m, p.k_r_n_per_m, p.k_u_n_per_m, p.r_m);
        let stiffness = [
            [kl + kr, kl - kr, -kl * r, -kr * r],
            [kl - kr, kl + kr + 4.0 * ku, -(kl + 2.0 * ku) * r, (kr + 2.0 * ku) * r],
            [-kl * r, -(kl + 2.0 * ku) * r, (kl + ku) * r * r, -ku * r * r],
            [-kr * r, (kr + 2.0 * ku) * r, -ku * r * r, (kr + ku) * r * r],
        ];
        let mass = [p.m_cart_kg, p.m_bridge_kg, p.j_m_kgm2, p.j_m_kgm2];
        let mut twin = Self {
            mass,
            stiffness,
            viscous: [p.b_cart_ns_per_m, p.b_bridge_ns_per_m, p.kt_nms, p.kt_nms],
            coulomb: [p.fc_cart_n, p.fc_bridge_n, p.t0_nm, p.t0_nm],
            r_m: r,
            drive_k: p.drive.stiffness_nm_per_rad,
            drive_max: p.drive.holding_torque_nm,
            omega_max: 0.0,
        };
        twin.omega_max = twin.undamped_modes_rad_s().last().copied().unwrap_or(0.0);
        if !(twin.omega_max.is_finite() && twin.omega_max > 0.0) {
            return Err(ModelError::Numerical("no finite vibration mode".into()));
        }
        Ok(twin)
    }

    /// Undamped natural frequencies (rad/s, ascending) of M⁻¹(K + drive stiffness),
    /// from the symmetric matrix M^-½ K M^-½.
    pub fn undamped_modes_rad_s(&self) -> Vec<f64> {
        let mut k = Matrix4::from_fn(|i, j| self.stiffness[i][j]);
        k[(2, 2)] += self.drive_k;
        k[(3, 3)] += self.drive_k;
        let s = Matrix4::from_fn(|i, j| k[(i, j)] / (self.mass[i] * self.mass[j]).sqrt());
        let mut w: Vec<f64> = SymmetricEigen::new(s).eigenvalues.iter().map(|l| l.max(0.0).sqrt()).collect();
        w.sort_by(f64::total_cmp);
        w
    }

    /// The integrator step for an output period: the largest h ≤ safety/ω_max that
    /// divides the period exactly.
    pub fn step_for(&self, sample_dt_s: f64, safety: f64) -> (f64, usize) {
        let target = (safety / self.omega_max).min(1e-3);
        let n = (sample_dt_s / target).ceil().max(1.0) as usize;
        (sample_dt_s / n as f64, n)
    }

    /// Generalised forces except Coulomb friction, and accelerations, for the given
    /// state, commanded motor angles and friction modes.
    #[inline]
    fn accel(&self, q: &[f64; 4], v: &[f64; 4], theta_cmd: [f64; 2], modes: &[Mode; 4]) -> [f64; 4] {
        let f = self.forces(q, v, theta_cmd);
        let mut a = [0.0; 4];
        for i in 0..4 {
            a[i] = match modes[i] {
                Mode::Stuck => 0.0,
                Mode::Slipping(s) => (f[i] - self.coulomb[i] * s) / self.mass[i],
            };
        }
        a
    }

    /// Spring, drive and viscous forces (no Coulomb term).
    #[inline]
    fn forces(&self, q: &[f64; 4], v: &[f64; 4], theta_cmd: [f64; 2]) -> [f64; 4] {
        let mut f = [0.0; 4];
        for (i, row) in self.stiffness.iter().enumerate() {
            f[i] = -(row[0] * q[0] + row[1] * q[1] + row[2] * q[2] + row[3] * q[3]) - self.viscous[i] * v[i];
        }
        for m in 0..2 {
            let t = self.drive_k * (theta_cmd[m] - q[2 + m]);
            f[2 + m] += t.clamp(-self.drive_max, self.drive_max);
        }
        f
    }

    fn theta_cmd(&self, cmd: &dyn MotorCommand, t: f64) -> [f64; 2] {
        let [s1, s2] = cmd.belt_m(t);
        [s1 / self.r_m, s2 / self.r_m]
    }

    /// Simulate from rest at the origin for `duration_s`, sampling every `sample_dt_s`.
    pub fn simulate(&self, cmd: &dyn MotorCommand, duration_s: f64, sample_dt_s: f64, safety: f64) -> Result<Trajectory, ModelError> {
        if !(sample_dt_s.is_finite() && sample_dt_s > 0.0) {
            return Err(ModelError::invalid("sample_dt_s", sample_dt_s, "must be > 0"));
        }
        if !(duration_s.is_finite() && duration_s >= 0.0 && duration_s / sample_dt_s <= 1e7) {
            return Err(ModelError::invalid("duration_s", duration_s, "must be ≥ 0 and at most 1e7 samples"));
        }
        if !(safety.is_finite() && safety > 0.0 && safety <= 1.0) {
            return Err(ModelError::invalid("safety", safety, "must be in (0, 1]"));
        }
        let samples = (duration_s / sample_dt_s).round() as usize;
        let (h, sub) = self.step_for(sample_dt_s, safety);
        let mut out = Trajectory { step_s: h, ..Default::default() };
        let mut q = [0.0f64; 4];
        let mut v = [0.0f64; 4];
        let mut modes = [Mode::Stuck; 4];
        self.record(&mut out, 0.0, &q, &v, cmd);
        let mut t = 0.0;
        for k in 0..samples {
            for j in 0..sub {
                self.step(&mut q, &mut v, &mut modes, t, h, cmd);
                t = (k * sub + j + 1) as f64 * h;
            }
            t = (k + 1) as f64 * sample_dt_s;
            self.record(&mut out, t, &q, &v, cmd);
        }
        if q.iter().chain(v.iter()).any(|x| !x.is_finite()) {
            return Err(ModelError::Numerical("the twin's state became non-finite".into()));
        }
        Ok(out)
    }

    /// One RK4 step with friction modes frozen, then stick/slip switching.
    fn step(&self, q: &mut [f64; 4], v: &mut [f64; 4], modes: &mut [Mode; 4], t: f64, h: f64, cmd: &dyn MotorCommand) {
        let th0 = self.theta_cmd(cmd, t);
        let thm = self.theta_cmd(cmd, t + 0.5 * h);
        let th1 = self.theta_cmd(cmd, t + h);
        // Break-away of stuck coordinates (velocity is zero, so no viscous term).
        let f0 = self.forces(q, v, th0);
        for i in 0..4 {
            if modes[i] == Mode::Stuck && f0[i].abs() > self.coulomb[i] {
                modes[i] = Mode::Slipping(f0[i].signum());
            }
        }
        let vel = |v: &[f64; 4]| -> [f64; 4] {
            let mut d = *v;
            for i in 0..4 {
                if modes[i] == Mode::Stuck {
                    d[i] = 0.0;
                }
            }
            d
        };
        let add = |a: &[f64; 4], b: &[f64; 4], s: f64| -> [f64; 4] { [a[0] + s * b[0], a[1] + s * b[1], a[2] + s * b[2], a[3] + s * b[3]] };
        let k1q = vel(v);
        let k1v = self.accel(q, v, th0, modes);
        let (q2, v2) = (add(q, &k1q, 0.5 * h), add(v, &k1v, 0.5 * h));
        let k2q = vel(&v2);
        let k2v = self.accel(&q2, &v2, thm, modes);
        let (q3, v3) = (add(q, &k2q, 0.5 * h), add(v, &k2v, 0.5 * h));
        let k3q = vel(&v3);
        let k3v = self.accel(&q3, &v3, thm, modes);
        let (q4, v4) = (add(q, &k3q, h), add(v, &k3v, h));
        let k4q = vel(&v4);
        let k4v = self.accel(&q4, &v4, th1, modes);
        for i in 0..4 {
            let q_new = q[i] + h / 6.0 * (k1q[i] + 2.0 * k2q[i] + 2.0 * k3q[i] + k4q[i]);
            let v_new = v[i] + h / 6.0 * (k1v[i] + 2.0 * k2v[i] + 2.0 * k3v[i] + k4v[i]);
            if let Mode::Slipping(s) = modes[i] {
                if v_new * s < 0.0 {
                    // Velocity reversed inside the step: stop at the interpolated zero
                    // crossing (linear velocity within the step) and stick there.
                    let theta = v[i] / (v[i] - v_new);
                    q[i] += 0.5 * theta * h * v[i];
                    v[i] = 0.0;
                    modes[i] = Mode::Stuck;
                    continue;
                }
            }
            q[i] = q_new;
            v[i] = if modes[i] == Mode::Stuck { 0.0 } else { v_new };
        }
    }

    fn record(&self, out: &mut Trajectory, t: f64, q: &[f64; 4], v: &[f64; 4], cmd: &dyn MotorCommand) {
        let [s1, s2] = cmd.belt_m(t);
        let [xc, yc] = super::kinematics::cartesian_from_motor(s1, s2);
        out.t_s.push(t);
        out.x_m.push(q[0]);
        out.vx_m_s.push(v[0]);
        out.y_m.push(q[1]);
        out.vy_m_s.push(v[1]);
        out.phi1_rad.push(q[2]);
        out.omega1_rad_s.push(v[2]);
        out.phi2_rad.push(q[3]);
        out.omega2_rad_s.push(v[3]);
        out.x_cmd_m.push(xc);
        out.y_cmd_m.push(yc);
    }
}

/// Simulate `params` on `cmd` with the default step safety.
pub fn simulate(params: &HbotParams, cmd: &dyn MotorCommand, duration_s: f64, sample_dt_s: f64) -> Result<Trajectory, ModelError> {
    Twin::new(params)?.simulate(cmd, duration_s, sample_dt_s, DEFAULT_SAFETY)
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Belt([f64; 2]);
    impl MotorCommand for Belt {
        /// Ramp both belts to the given displacement over 0.2 s.
        fn belt_m(&self, t: f64) -> [f64; 2] {
            let f = (t / 0.2).clamp(0.0, 1.0);
            [self.0[0] * f, self.0[1] * f]
        }
    }

    fn last(v: &[f64]) -> f64 {
        v.last().copied().unwrap_or(f64::NAN)
    }

    #[test]
    fn at_rest_without_drive_nothing_moves() {
        let tr = simulate(&HbotParams::source_identified(), &Belt([0.0, 0.0]), 0.5, 0.01).expect("sim");
        for col in [&tr.x_m, &tr.y_m, &tr.phi1_rad, &tr.phi2_rad] {
            assert!(col.iter().all(|v| *v == 0.0), "something moved");
        }
    }

    #[test]
    fn opposite_motor_motion_moves_only_y_and_equal_only_x() {
        let p = HbotParams::source_identified();
        let ty = simulate(&p, &Belt([5e-3, -5e-3]), 0.6, 0.01).expect("sim");
        // kL = kR: the cart sees no net belt force, and with Coulomb friction it stays exactly put.
        assert!(ty.x_m.iter().all(|x| *x == 0.0), "cart moved on a y move");
        // 5 mm commanded; the bridge ends within the friction/compliance band (±0.2 mm).
        assert!((last(&ty.y_m) - 5e-3).abs() < 2e-4, "y = {}", last(&ty.y_m));
        let tx = simulate(&p, &Belt([5e-3, 5e-3]), 0.6, 0.01).expect("sim");
        assert!(tx.y_m.iter().all(|y| *y == 0.0), "bridge moved on an x move");
        assert!((last(&tx.x_m) - 5e-3).abs() < 2e-4, "x = {}", last(&tx.x_m));
        // Mirror symmetry: the negative move is the exact mirror image.
        let tm = simulate(&p, &Belt([-5e-3, 5e-3]), 0.6, 0.01).expect("sim");
        for (a, b) in ty.y_m.iter().zip(&tm.y_m) {
            assert!((a + b).abs() < 1e-15);
        }
    }

    #[test]
    fn belt_modes_near_770_rad_s() {
        let twin = Twin::new(&HbotParams::source_identified()).expect("twin");
        let w = twin.undamped_modes_rad_s();
        // Source digest: coupled belt modes near 770 rad/s with the identified values.
        assert!(w[3] > 700.0 && w[3] < 800.0, "{w:?}");
        assert!(w[2] > 700.0 && w[2] < 800.0, "{w:?}");
    }

    #[test]
    fn step_size_converges() {
        // Halving the step (safety 0.2 → 0.1) changes the trajectory by < 0.5 µm: the
        // default step is converged well below the laser's noise (µm level).
        let p = HbotParams::source_identified();
        let mv = LinearMove::constant_speed(0.0, 8e-3, 0.75).expect("move");
        let twin = Twin::new(&p).expect("twin");
        let a = twin.simulate(&mv, 1.0, 0.01, 0.2).expect("sim");
        let b = twin.simulate(&mv, 1.0, 0.01, 0.1).expect("sim");
        let worst = crate::metrics::max_abs_error(&a.y_m, &b.y_m);
        assert!(worst < 5e-7, "max difference {worst} m");
    }

    /// Holds both motors at their start angle.
    struct Hold;
    impl MotorCommand for Hold {
        fn belt_m(&self, _t: f64) -> [f64; 2] {
            [0.0, 0.0]
        }
    }

    /// Run the twin's own stepper from a given state with the motors held.
    fn free_run(twin: &Twin, mut q: [f64; 4], mut v: [f64; 4], duration_s: f64) -> (Vec<[f64; 4]>, Vec<[f64; 4]>, f64) {
        let (h, _) = twin.step_for(1e-3, DEFAULT_SAFETY);
        let mut modes = v.map(|vi| if vi == 0.0 { Mode::Stuck } else { Mode::Slipping(vi.signum()) });
        let (mut qs, mut vs) = (vec![q], vec![v]);
        for k in 0..(duration_s / h).round() as usize {
            twin.step(&mut q, &mut v, &mut modes, k as f64 * h, h, &Hold);
            qs.push(q);
            vs.push(v);
        }
        (qs, vs, h)
    }

    /// Lossless parameters with kL = kR, where the modes separate into an x–φ₊
    /// and a y–φ₋ pair (φ± = (φ1 ± φ2)/2).
    fn lossless() -> HbotParams {
        HbotParams {
            t0_nm: 0.0,
            kt_nms: 0.0,
            b_cart_ns_per_m: 0.0,
            b_bridge_ns_per_m: 0.0,
            fc_cart_n: 0.0,
            fc_bridge_n: 0.0,
            ..HbotParams::source_identified()
        }
    }

    /// ω² of a two-mass pair with M⁻¹K = [[a, −b], [−c, d]]: roots of
    /// ω⁴ − (a + d)ω² + (ad − bc) = 0.
    fn pair(a: f64, b: f64, c: f64, d: f64) -> [f64; 2] {
        let (sum, prod) = (a + d, a * d - b * c);
        let disc = (sum * sum - 4.0 * prod).sqrt();
        [(sum - disc) / 2.0, (sum + disc) / 2.0]
    }

    #[test]
    fn stiffness_has_the_two_rigid_body_motions_of_the_kinematics_as_null_space() {
        // Moving the cart by x and the bridge by y while each pulley turns by its
        // belt's displacement / r (Δs1 = x + y, Δs2 = x − y, the H-Bot kinematics)
        // stretches no belt: K must vanish on both motions and be positive on the rest.
        let p = HbotParams::initial_estimate();
        let twin = Twin::new(&HbotParams { k_r_n_per_m: 1.3e5, ..p }).expect("twin");
        let k = Matrix4::from_fn(|i, j| twin.stiffness[i][j]);
        for (x, y) in [(1e-3, 0.0), (0.0, 1e-3), (2e-3, -5e-4)] {
            let [s1, s2] = motor_from_cartesian(x, y);
            let q = nalgebra::Vector4::new(x, y, s1 / p.r_m, s2 / p.r_m);
            // Relative to the size of the terms that cancel (‖K‖‖q‖): rounding only.
            assert!((k * q).norm() < 1e-14 * k.norm() * q.norm(), "K q = {:?}", k * q);
        }
        let mut ev: Vec<f64> = SymmetricEigen::new(k).eigenvalues.iter().copied().collect();
        ev.sort_by(f64::total_cmp);
        let scale = ev[3];
        assert!(ev[0].abs() < 1e-12 * scale && ev[1].abs() < 1e-12 * scale, "rank must be 2: {ev:?}");
        assert!(ev[2] > 1e-6 * scale, "{ev:?}");
    }

    #[test]
    fn modes_match_the_analytic_pairs_and_a_free_vibration_has_their_period() {
        let p = lossless();
        let (k, ku, r, j, kd) = (p.k_l_n_per_m, p.k_u_n_per_m, p.r_m, p.j_m_kgm2, p.drive.stiffness_nm_per_rad);
        // x–φ₊: m x'' = −2k x + 2kr φ₊,  J φ₊'' = kr x − (kr² + kd) φ₊.
        let x_pair = pair(2.0 * k / p.m_cart_kg, 2.0 * k * r / p.m_cart_kg, k * r / j, (k * r * r + kd) / j);
        // y–φ₋: m y'' = −(2k + 4ku) y + 2(k + 2ku) r φ₋,  J φ₋'' = (k + 2ku) r y − ((k + 2ku) r² + kd) φ₋.
        let k2 = k + 2.0 * ku;
        let y_pair = pair(2.0 * k2 / p.m_bridge_kg, 2.0 * k2 * r / p.m_bridge_kg, k2 * r / j, (k2 * r * r + kd) / j);
        let mut want: Vec<f64> = x_pair.iter().chain(&y_pair).map(|w2| w2.sqrt()).collect();
        want.sort_by(f64::total_cmp);
        let twin = Twin::new(&p).expect("twin");
        for (got, want) in twin.undamped_modes_rad_s().iter().zip(&want) {
            assert!((got / want - 1.0).abs() < 1e-9, "{got} vs {want}");
        }
        // Start exactly on the slow x–φ₊ eigenvector and time the zero crossings of x.
        let w2 = x_pair[0];
        let x0 = 1e-4;
        let phi = (2.0 * k / p.m_cart_kg - w2) * x0 * p.m_cart_kg / (2.0 * k * r);
        let period = std::f64::consts::TAU / w2.sqrt();
        let (qs, _, h) = free_run(&twin, [x0, 0.0, phi, phi], [0.0; 4], 5.5 * period);
        let ups: Vec<f64> =
            qs.windows(2).enumerate().filter(|(_, w)| w[0][0] < 0.0 && w[1][0] >= 0.0).map(|(i, w)| (i as f64 + w[0][0] / (w[0][0] - w[1][0])) * h).collect();
        assert_eq!(ups.len(), 5, "{ups:?}");
        let measured = (ups[4] - ups[0]) / 4.0;
        // The stick/slip switch resets a reversing velocity to zero at the
        // interpolated turning point; that shifts the phase by at most one step per
        // reversal, two per period: |ΔT| ≤ 2h.
        assert!((measured - period).abs() < 2.0 * h, "period {measured} s vs {period} s (h = {h} s)");
        // A mode shape stays a mode shape: y and φ₋ move only by rounding (the two
        // rotor rows sum in different orders), 1e-6 of the amplitude at most.
        let (y_max, split_max) = (crate::metrics::nan_max(qs.iter().map(|q| q[1].abs())), crate::metrics::nan_max(qs.iter().map(|q| (q[2] - q[3]).abs())));
        assert!(y_max < 1e-6 * x0 && split_max < 1e-6 * phi.abs(), "y {y_max} m, φ1 − φ2 {split_max} rad");
    }

    #[test]
    fn coulomb_friction_stops_a_rigid_slide_after_m_v2_over_2f() {
        // Cart sliding with the belt as one rigid body (pulleys turning at v/r, no
        // belt stretch), motors free (no drive spring, no motor losses), only the
        // cart's Coulomb friction Fc: energy balance gives the stop distance
        // d = m_eff v²/(2 Fc) at t = m_eff v/Fc, with m_eff = m_cart + 2 J/r².
        let p = HbotParams { j_m_kgm2: 1e-5, fc_cart_n: 5.0, ..lossless() };
        let mut twin = Twin::new(&p).expect("twin");
        twin.drive_k = 0.0;
        let v0 = 0.3;
        let m_eff = p.m_cart_kg + 2.0 * p.j_m_kgm2 / (p.r_m * p.r_m);
        let (d, t_stop) = (m_eff * v0 * v0 / (2.0 * p.fc_cart_n), m_eff * v0 / p.fc_cart_n);
        let (qs, vs, h) = free_run(&twin, [0.0; 4], [v0, 0.0, v0 / p.r_m, v0 / p.r_m], 1.5 * t_stop);
        let stop = vs.iter().position(|v| v[0] == 0.0).expect("the cart stops");
        let x_end = qs.last().map(|q| q[0]).unwrap_or(f64::NAN);
        // The belt between cart and pulleys carries the pulleys' deceleration force
        // (2J/r²)·Fc/m_eff ≈ 1.7 N, a static stretch of 1.7 N/(kL + kR) = 4 µm that
        // rings undamped: the cart's end point is within twice that, 10 µm.
        let ring = 2.0 * (2.0 * p.j_m_kgm2 / (p.r_m * p.r_m)) * p.fc_cart_n / m_eff / (p.k_l_n_per_m + p.k_r_n_per_m);
        assert!((x_end - d).abs() < ring.max(1e-5), "stopped at {x_end} m, analytic {d} m");
        // The ringing adds a velocity up to ω_max·ring: the cart's velocity reverses
        // (and sticks) when the rigid slide has slowed to that, ring·ω_max/Fc·m_eff early.
        let early = ring * twin.omega_max * m_eff / p.fc_cart_n;
        assert!((stop as f64 * h - t_stop).abs() < early + h, "stop at {} s, analytic {t_stop} s", stop as f64 * h);
        assert!(qs[stop..].iter().all(|q| q[0] == qs[stop][0]), "the cart stays stuck once stopped");
    }
}
