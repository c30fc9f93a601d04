#!/usr/bin/env python3
"""Plain-Python side of `fdmlab bench turns`: the same work as fdmlab's streaming
reader (datasets/src/gcode/stream.rs) — G0/G1, G2/G3 arcs linearised into chords
within 5 µm, G90/G91, M82/M83, G92, G28, G20/G21, modal F, M204, layer and type
markers, zero-length and non-XY lines dropped — written the way one would in
plain Python (str.split, float), timed on one core.

Usage: python3 benches/turns_reader.py FILE.gcode
Prints one JSON object: {"seconds": …, "bytes": …, "moves": …, "mb_per_s": …}.
"""
import json
import math
import sys
import time


def read(path, tol=0.005):
    pos = [0.0, 0.0, 0.0, 0.0]
    abs_xyz, abs_e, scale, feed = True, True, 1.0, 0.0
    print_accel = travel_accel = 0.0
    layer, emitted, feature = 0, False, ""
    moves = 0
    with open(path, "rb") as f:
        for raw in f:
            line = raw.decode("utf-8", "replace")
            code, _, comment = line.partition(";")
            comment = comment.strip()
            if comment.startswith("LAYER_CHANGE") or comment.startswith("LAYER:"):
                if emitted:
                    layer += 1
                    emitted = False
            elif comment.startswith("TYPE:"):
                feature = comment[5:].strip()
            code = code.split("*")[0].split()
            if not code:
                continue
            if code[0][0] in "Nn" and code[0][1:].isdigit():
                code = code[1:]
                if not code:
                    continue
            name = code[0].upper()
            if name in ("M23", "M28", "M30", "M32", "M117", "M118", "M928"):
                continue  # free text
            words = {}
            for tok in code[1:]:
                try:
                    words[tok[0].upper()] = float(tok[1:]) if len(tok) > 1 else float("nan")
                except ValueError:
                    # Like the Rust reader's motion mode: non-numeric words of M
                    # commands (`M115 U3.11.0`, `M862.3 P "MK3S"`) read as NaN.
                    if name.startswith("G"):
                        raise
                    words[tok[0].upper()] = float("nan")
            if name in ("G0", "G1", "G00", "G01", "G2", "G3", "G02", "G03"):
                if "F" in words:
                    feed = words["F"] * scale / 60.0
                start = list(pos)
                for i, l in enumerate("XYZE"):
                    if l in words:
                        a = abs_xyz if i < 3 else abs_e
                        pos[i] = words[l] * scale if a else pos[i] + words[l] * scale
                if name in ("G0", "G1", "G00", "G01"):
                    if pos[0] != start[0] or pos[1] != start[1]:
                        moves += 1
                        emitted = True
                    continue
                # Arc about the I/J centre or from R.
                sx, sy, ex, ey = start[0], start[1], pos[0], pos[1]
                ccw = name in ("G3", "G03")
                if "R" in words:
                    r = words["R"] * scale
                    dx, dy = ex - sx, ey - sy
                    d = math.hypot(dx, dy)
                    h = math.sqrt(max(r * r - d * d / 4.0, 0.0))
                    side = 1.0 if ccw != (r < 0) else -1.0
                    cx, cy = (sx + ex) / 2 - side * h * dy / d, (sy + ey) / 2 + side * h * dx / d
                else:
                    cx, cy = sx + words.get("I", 0.0) * scale, sy + words.get("J", 0.0) * scale
                r0 = math.hypot(sx - cx, sy - cy)
                a0 = math.atan2(sy - cy, sx - cx)
                a1 = math.atan2(ey - cy, ex - cx)
                sweep = (a1 - a0) % (2 * math.pi) if ccw else -((a0 - a1) % (2 * math.pi))
                if sweep == 0 and sx == ex and sy == ey:
                    sweep = 2 * math.pi if ccw else -2 * math.pi
                n = max(1, math.ceil(abs(sweep) / (2 * math.acos(1 - tol / r0)))) if tol < r0 else 1
                px, py = sx, sy
                for k in range(1, n + 1):
                    t = k / n
                    x, y = (cx + r0 * math.cos(a0 + sweep * t), cy + r0 * math.sin(a0 + sweep * t)) if k < n else (ex, ey)
                    if x != px or y != py:
                        moves += 1
                        emitted = True
                    px, py = x, y
            elif name == "G90":
                abs_xyz = True
            elif name == "G91":
                abs_xyz = False
            elif name == "M82":
                abs_e = True
            elif name == "M83":
                abs_e = False
            elif name == "G20":
                scale = 25.4
            elif name == "G21":
                scale = 1.0
            elif name == "G92":
                for i, l in enumerate("XYZE"):
                    if l in words:
                        pos[i] = words[l] * scale
            elif name == "G28":
                named = [l in words for l in "XYZ"]
                for i in range(3):
                    if named[i] or not any(named):
                        pos[i] = 0.0
            elif name == "M204":
                if "S" in words:
                    print_accel = travel_accel = words["S"]
                print_accel = words.get("P", print_accel)
                travel_accel = words.get("T", travel_accel)
    return moves


def main():
    path = sys.argv[1]
    t = time.perf_counter()
    moves = read(path)
    s = time.perf_counter() - t
    size = __import__("os").path.getsize(path)
    print(json.dumps({"seconds": s, "bytes": size, "moves": moves, "mb_per_s": size / s / 1e6}))


if __name__ == "__main__":
    main()
