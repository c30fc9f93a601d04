#!/usr/bin/env python3
"""SIPPY N4SID baseline for `fdmlab bench thermal`.

Reads a hotend log CSV (time_s,heater_duty,fan_duty,temperature_c[,...,ambient_c]),
identifies N4SID models of the given orders with SIPPY (pip package `sippy-unipi`)
on the temperature rise above ambient with the heater duty as input, and prints
JSON: per order the identification time and the simulation fit %
100*(1 - ||y - yhat|| / ||y - mean(y)||) from a zero initial state (the log
starts cold, so this matches fdmlab's equilibrium initial-state rule).

usage: thermal_sippy.py LOG.csv [--orders 1..8] [--horizon 20] [--inputs heater_duty]
"""
import argparse
import csv
import json
import sys
import time

import numpy as np
from sippy_unipi import system_identification


def load(path, inputs):
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    y = np.array([float(r["temperature_c"]) for r in rows])
    ambient = float(rows[0]["ambient_c"]) if "ambient_c" in rows[0] else y[0]
    u = np.array([[float(r[name]) for r in rows] for name in inputs])
    return y - ambient, u


def simulate(A, B, C, D, u):
    n = A.shape[0]
    x = np.zeros(n)
    out = np.empty(u.shape[1])
    for k in range(u.shape[1]):
        out[k] = C @ x + D @ u[:, k]
        x = A @ x + B @ u[:, k]
    return out


def fit_percent(y, yhat):
    return 100.0 * (1.0 - np.linalg.norm(y - yhat) / np.linalg.norm(y - y.mean()))


def main():
    p = argparse.ArgumentParser()
    p.add_argument("log")
    p.add_argument("--orders", default="1..8")
    p.add_argument("--horizon", type=int, default=20)
    p.add_argument("--inputs", default="heater_duty")
    a = p.parse_args()
    lo, hi = (int(v) for v in a.orders.split(".."))
    y, u = load(a.log, a.inputs.split(","))
    results = []
    total = 0.0
    for n in range(lo, hi + 1):
        t0 = time.perf_counter()
        sys_id = system_identification(y, u, "N4SID", SS_fixed_order=n, SS_f=a.horizon, SS_p=a.horizon)
        dt = time.perf_counter() - t0
        total += dt
        A, B, C, D = (np.atleast_2d(np.asarray(m, dtype=float)) for m in (sys_id.A, sys_id.B, sys_id.C, sys_id.D))
        yhat = simulate(A, B, C.reshape(-1), D.reshape(-1), u)
        fit = fit_percent(y, yhat) if np.all(np.isfinite(yhat)) else float("-inf")
        results.append({"order": n, "seconds": dt, "fit_percent": fit})
    json.dump({"tool": "sippy-unipi N4SID", "samples": int(y.size), "horizon": a.horizon, "total_seconds": total, "orders": results}, sys.stdout)
    sys.stdout.write("\n")


if __name__ == "__main__":
    main()
