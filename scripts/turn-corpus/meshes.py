"""Procedural meshes of the full turn corpus (issue #25 item 1), written as
ASCII STL by Python, so every vertex follows from the seed: boat hulls, lofts,
sweeps, figurine-like blobs with scan-like noise, vases and multi-part plates.

Every body is a stack of closed rings (one per z level, the same point count,
counter-clockwise seen from above) capped by fans at both ends: a closed,
consistently wound mesh whatever the ring shapes.
"""
import math


def ring_stack(rings):
    """Triangles of a closed body from rings [(z, [(x, y), ...]), ...] bottom to top."""
    tris = []
    k = len(rings[0][1])
    pts = [[(x, y, z) for x, y in ring] for z, ring in rings]
    for a, b in zip(pts, pts[1:]):
        for i in range(k):
            j = (i + 1) % k
            tris.append((a[i], a[j], b[j]))
            tris.append((a[i], b[j], b[i]))
    for ring, up in ((pts[0], False), (pts[-1], True)):
        c = (sum(p[0] for p in ring) / k, sum(p[1] for p in ring) / k, ring[0][2])
        for i in range(k):
            j = (i + 1) % k
            tris.append((c, ring[i], ring[j]) if up else (c, ring[j], ring[i]))
    return tris


def write_stl(path, bodies):
    """Write bodies (lists of triangles) as one ASCII STL, normals from the winding."""
    with open(path, "w") as f:
        f.write("solid fdmlab\n")
        for tris in bodies:
            for a, b, c in tris:
                u = [b[i] - a[i] for i in range(3)]
                v = [c[i] - a[i] for i in range(3)]
                n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]
                ln = math.sqrt(sum(x * x for x in n)) or 1.0
                f.write("  facet normal %.6f %.6f %.6f\n    outer loop\n" % tuple(x / ln for x in n))
                for p in (a, b, c):
                    f.write("      vertex %.4f %.4f %.4f\n" % p)
                f.write("    endloop\n  endfacet\n")
        f.write("endsolid fdmlab\n")


def polar(k, radius, cx=0.0, cy=0.0, phase=0.0):
    """A ring of k points at radius(theta) about (cx, cy)."""
    out = []
    for i in range(k):
        t = phase + 2 * math.pi * i / k
        r = radius(t)
        out.append((cx + r * math.cos(t), cy + r * math.sin(t)))
    return out


def boat(p, rng):
    """A hull: sections of a flat-bottomed half ellipse lofted along the length,
    the beam tapering to a pointed bow and a transom, the sheer rising to the bow."""
    length, beam, depth, k = p["length"], p["beam"], p["depth"], 64
    rings = []
    for s in range(p["stations"] + 1):
        z = depth * s / p["stations"]
        ring = []
        # Each waterline: the outline of the hull at height z, bow at +x.
        width = beam / 2 * (0.45 + 0.55 * math.sqrt(max(z / depth, 0.0)))
        bow = length / 2 * (0.8 + 0.2 * z / depth)
        for i in range(k):
            t = 2 * math.pi * i / k
            c, sn = math.cos(t), math.sin(t)
            if c >= 0:  # fore: pointed (superellipse exponent p["bow_shape"])
                x = bow * abs(c) ** (2 / p["bow_shape"])
            else:  # aft: a full transom
                x = -length / 2 * abs(c) ** 0.35
            y = width * math.copysign(abs(sn) ** (2 / 2.6), sn)
            ring.append((x, y))
        rings.append((z, ring))
    return [ring_stack(rings)]


def loft(p, rng):
    """A loft from an n-gon at the base to a rounded m-lobed top, twisted."""
    k, h = 96, p["height"]
    base = lambda t: p["r0"] * math.cos(math.pi / p["n"]) / math.cos((t % (2 * math.pi / p["n"])) - math.pi / p["n"])
    top = lambda t: p["r1"] * (1 + 0.18 * math.cos(p["m"] * t))
    rings = []
    for s in range(p["stations"] + 1):
        f = s / p["stations"]
        tw = math.radians(p["twist"]) * f
        rings.append((h * f, polar(k, lambda t: (1 - f) * base(t - tw) + f * top(t - tw), phase=0.0)))
    return [ring_stack(rings)]


def sweep(p, rng):
    """A rounded-square section swept up a leaning S-curve (a bent pillar)."""
    k, h, r = 72, p["height"], p["section"]
    sq = lambda t: r / (abs(math.cos(t)) ** 4 + abs(math.sin(t)) ** 4) ** 0.25
    rings = []
    for s in range(p["stations"] + 1):
        f = s / p["stations"]
        cx = p["sway"] * math.sin(math.pi * f * p["bends"])
        cy = p["sway"] * 0.5 * (1 - math.cos(math.pi * f))
        rings.append((h * f, polar(k, sq, cx, cy, phase=math.radians(p["twist"]) * f)))
    return [ring_stack(rings)]


def blob(p, rng):
    """A figurine-like body: a spheroid with a few seeded bumps (limbs, head),
    its vertices moved by seeded noise of `noise` mm as a 3D scan's are."""
    k, h = 90, p["height"]
    bumps = [(rng.uniform(0, 2 * math.pi), rng.uniform(0.15, 0.85), rng.uniform(0.15, 0.35), rng.uniform(0.2, 0.5)) for _ in range(p["bumps"])]
    rings = []
    for s in range(p["stations"] + 1):
        f = s / p["stations"]
        z = h * f
        body = p["radius"] * (0.35 + 0.65 * math.sin(math.pi * (0.08 + 0.84 * f)))

        def radius(t):
            r = body
            for th, zc, w, a in bumps:
                d = math.atan2(math.sin(t - th), math.cos(t - th))
                r += p["radius"] * a * math.exp(-(d / 0.6) ** 2 - ((f - zc) / w) ** 2)
            return r

        ring = polar(k, radius)
        ring = [(x + rng.gauss(0, p["noise"]), y + rng.gauss(0, p["noise"])) for x, y in ring]
        rings.append((z, ring))
    return [ring_stack(rings)]


def vase(p, rng):
    """A vase: a surface of revolution with a wavy profile and m lobes."""
    k, h = 120, p["height"]
    rings = []
    for s in range(p["stations"] + 1):
        f = s / p["stations"]
        prof = p["radius"] * (0.7 + 0.3 * math.sin(math.pi * (0.2 + p["waves"] * f)))
        rings.append((h * f, polar(k, lambda t: prof * (1 + p["lobe"] * math.cos(p["m"] * t + 2 * math.pi * p["spin"] * f)))))
    return [ring_stack(rings)]


def plate(p, rng):
    """A multi-part plate: small disjoint parts (pegs, n-gon prisms, twisted
    lofts, bumpy blobs) on a grid, as one mesh."""
    bodies = []
    cols = math.ceil(math.sqrt(p["parts"]))
    for i in range(p["parts"]):
        cx = (i % cols - (cols - 1) / 2) * p["pitch"]
        cy = (i // cols - (cols - 1) / 2) * p["pitch"]
        kind = rng.choice(["peg", "prism", "twist", "bump"])
        h = rng.uniform(3, 8)
        r = rng.uniform(2.5, p["pitch"] / 2.6)
        n = rng.choice([3, 4, 5, 6, 8])
        if kind == "peg":
            rings = [(z, polar(48, lambda t: r, cx, cy)) for z in (0.0, h)]
        elif kind == "prism":
            rings = [(z, polar(n, lambda t: r, cx, cy)) for z in (0.0, h)]
        elif kind == "twist":
            rings = [(h * s / 12, polar(n * 8, lambda t, s=s: r * math.cos(math.pi / n) / math.cos((t - 0.08 * s) % (2 * math.pi / n) - math.pi / n), cx, cy)) for s in range(13)]
        else:
            rings = [(h * s / 16, polar(40, lambda t, s=s: r * (0.6 + 0.4 * math.sin(math.pi * (0.1 + 0.8 * s / 16))) * (1 + 0.1 * math.cos(5 * t)), cx, cy)) for s in range(17)]
        bodies.append(ring_stack(rings))
    return bodies


GENERATORS = {"boat": boat, "loft": loft, "sweep": sweep, "blob": blob, "vase": vase, "plate": plate}
