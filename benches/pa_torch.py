#!/usr/bin/env python3
"""PyTorch side of `fdmlab bench pa`: the same K_A network, data, scaling and
optimiser schedule as fdmlab's burn trainer, timed on CPU.

Usage: python3 benches/pa_torch.py GRID.csv [--epochs 500] [--batch 128] [--threads 2]
Prints one JSON object: {"seconds": …, "epochs": …, "rows": …, "train_mae": …}.
The grid CSV comes from `fdmlab ka grid -o GRID.csv`.
"""
import argparse, csv, json, math, time

import torch


def load(path):
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    feats = ["material", "extruder", "hotend_c", "nozzle_setting_mm", "layer_mm"]
    cols = []
    for name in feats:
        vals = [r[name] for r in rows]
        try:
            [float(v) for v in vals]
            cols.append([[float(v)] for v in vals])
        except ValueError:
            levels = sorted(set(vals))
            cols.append([[1.0 if v == l else 0.0 for l in levels] for v in vals])
    x = [sum((c[i] for c in cols), []) for i in range(len(rows))]
    y = [float(r["k_a"]) for r in rows]
    return torch.tensor(x, dtype=torch.float32), torch.tensor(y, dtype=torch.float32).unsqueeze(1)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("grid")
    ap.add_argument("--epochs", type=int, default=500)
    ap.add_argument("--batch", type=int, default=128)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--lr", type=float, default=0.01)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    torch.manual_seed(7)
    x, y = load(a.grid)
    lo, hi = x.min(0).values, x.max(0).values
    span = torch.where(hi > lo, hi - lo, torch.ones_like(hi))
    xs = (x - lo) / span
    ylo, yhi = y.min(), y.max()
    ys = (y - ylo) / (yhi - ylo)
    d = xs.shape[1]
    net = torch.nn.Sequential(
        torch.nn.Linear(d, 64), torch.nn.ReLU(),
        torch.nn.Linear(64, 64), torch.nn.ReLU(),
        torch.nn.Linear(64, 32), torch.nn.Sigmoid(),
        torch.nn.Linear(32, 1),
    )
    opt = torch.optim.Adam(net.parameters(), lr=a.lr, eps=1e-5)
    n = xs.shape[0]
    t0 = time.perf_counter()
    for epoch in range(a.epochs):
        lr = a.lr * (0.02 + 0.98 * 0.5 * (1 + math.cos(math.pi * epoch / a.epochs)))
        for g in opt.param_groups:
            g["lr"] = lr
        perm = torch.randperm(n)
        for i in range(0, n, a.batch):
            idx = perm[i:i + a.batch]
            opt.zero_grad()
            loss = ((net(xs[idx]) - ys[idx]) ** 2).mean()
            loss.backward()
            opt.step()
    secs = time.perf_counter() - t0
    with torch.no_grad():
        p = net(xs) * (yhi - ylo) + ylo
        mae = (p - y).abs().mean().item()
    print(json.dumps({"seconds": secs, "epochs": a.epochs, "rows": n, "train_mae": mae, "torch": torch.__version__}))


if __name__ == "__main__":
    main()
