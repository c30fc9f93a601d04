#!/usr/bin/env python3
"""Side-by-side baseline for `fdmlab bench hbot`: the same 8-state H-Bot equations
(Cao, Bi & Zou 2021, eqs. 7-10, with the fdmlab stepper drive and Coulomb friction)
integrated by scipy's solve_ivp, versus the fdmlab binary on the same move.

Friction in solve_ivp uses the Karnopp rule inside the right-hand side (a coordinate
whose speed is below V_EPS and whose net force is within the Coulomb level has zero
acceleration), the standard way to feed stick/slip to an adaptive solver.

Usage: python benches/hbot_scipy.py [path/to/fdmlab]   (release binary recommended)
Prints a JSON object with both timings, the ratio and the end positions.
"""
import json
import subprocess
import sys
import time

import numpy as np
from scipy.integrate import solve_ivp

# HbotParams::source_identified() + StepperDrive::default()
R, T0, KT, JM = 6.37e-3, 1.3e-2, 7e-3, 6e-4
MC, MB, KL, KR, KU = 0.7, 1.42, 2e5, 2e5, 1e5
BC, BB, FCC, FCB = 4.0, 33.0, 0.3, 9.0
KS, THOLD = 2.85, 0.4
V_EPS = 1e-6

K = np.array([
    [KL + KR, KL - KR, -KL * R, -KR * R],
    [KL - KR, KL + KR + 4 * KU, -(KL + 2 * KU) * R, (KR + 2 * KU) * R],
    [-KL * R, -(KL + 2 * KU) * R, (KL + KU) * R * R, -KU * R * R],
    [-KR * R, (KR + 2 * KU) * R, -KU * R * R, (KR + KU) * R * R],
])
M = np.array([MC, MB, JM, JM])
B = np.array([BC, BB, KT, KT])
C = np.array([FCC, FCB, T0, T0])

DIST, MOVE_S, SIM_S = 8e-3, 0.75, 1.0


def command(t):
    y = DIST * min(max(t / MOVE_S, 0.0), 1.0)
    return np.array([y / R, -y / R])  # s1 = y, s2 = -y


def rhs(t, s):
    q, v = s[0::2], s[1::2]
    f = -K @ q - B * v
    th = command(t)
    f[2:] += np.clip(KS * (th - q[2:]), -THOLD, THOLD)
    a = np.empty(4)
    for i in range(4):
        if abs(v[i]) < V_EPS and abs(f[i]) <= C[i]:
            a[i] = 0.0
        else:
            sgn = np.sign(v[i]) if abs(v[i]) >= V_EPS else np.sign(f[i])
            a[i] = (f[i] - C[i] * sgn) / M[i]
    out = np.empty(8)
    out[0::2], out[1::2] = v, a
    return out


def run_scipy(method):
    t_eval = np.arange(0, SIM_S + 1e-9, 0.01)
    start = time.perf_counter()
    sol = solve_ivp(rhs, (0, SIM_S), np.zeros(8), method=method, t_eval=t_eval, rtol=1e-6, atol=1e-9, max_step=1e-3)
    elapsed = time.perf_counter() - start
    return elapsed, sol


def main():
    fdmlab = sys.argv[1] if len(sys.argv) > 1 else "/work/target-release/release/fdmlab"
    res = {}
    # LSODA and Radau were tried too: with the discontinuous friction they shrink their
    # steps at every stick/slip switch and did not finish within a minute, so RK45 is the baseline.
    for method in ["RK45"]:
        times = []
        for _ in range(3):
            el, sol = run_scipy(method)
            times.append(el)
        y = sol.y[2]
        res[method] = {"seconds": sorted(times)[1], "nfev": int(sol.nfev), "y_at_stop_mm": float(y[75] * 1e3), "y_end_mm": float(y[-1] * 1e3)}
    out = subprocess.run([fdmlab, "--json", "bench", "hbot"], check=True, capture_output=True, text=True).stdout
    rust = json.loads(out)
    rust_s = rust["simulate_1s_seconds"]
    for method in res:
        res[method]["ratio_vs_fdmlab"] = res[method]["seconds"] / rust_s
    print(json.dumps({"scipy": res, "fdmlab": rust}, indent=2))


if __name__ == "__main__":
    main()
