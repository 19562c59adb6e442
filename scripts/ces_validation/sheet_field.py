#!/usr/bin/env python3
"""The particles' own field at the drum, measured on a run's state (docs/CES.md, "Crowding").

The field model leaves the particles' charges out: each particle feels its own image only. This script takes the
state a run ended in (DIR/ces_particles.csv and DIR/checkpoint/ces_config.json; stop a run while the drum is loaded,
e.g. `--set duration_s=0.45` with the feed on until 0.3 s) and, for every copper SPHERE touching the drum, compares

  E_applied = q / ((2/3) pi^3 eps0 r^2)   the applied normal field at its contact, read back from its charge (a metal
                                          on the drum carries the induced charge of a sphere on an earthed plane,
                                          Lebedev & Skal'skaya; the model sets it from the applied field alone)
  dE        = sum over every other particle k still in the machine of the normal field at the contact point of q_k
              and of its image -q_k mirrored through the drum's surface (the plane approximation, heights << R)

and prints the mean and the spread of dE / E_applied, with the areal density of the particles within 2 mm of the
drum's surface. Usage: sheet_field.py RUN_DIR [RUN_DIR ...]
"""
import csv
import json
import math
import os
import sys

EPS0 = 8.8541878128e-12
K = 1 / (4 * math.pi * EPS0)


def load(run):
    cfg = json.load(open(os.path.join(run, "checkpoint", "ces_config.json")))
    doc = cfg.get("document", cfg)
    ces = doc["ces"] if "ces" in doc else doc
    R = ces["drum"]["diameter_mm"] * 1e-3 / 2
    W = ces["drum"]["width_mm"] * 1e-3
    parts = []
    with open(os.path.join(run, "ces_particles.csv")) as f:
        for r in csv.DictReader(f):
            if r["status"] == "collected":
                continue
            parts.append((r["material"], r["shape"], float(r["radius_m"]), float(r["charge_C"]),
                          float(r["x"]), float(r["y"]), float(r["z"])))
    return R, W, parts


def measure(run):
    R, W, parts = load(run)
    ratios = []
    near = 0
    for (_, _, r, _, x, y, _) in parts:
        if math.hypot(x, y) - R < 2e-3:
            near += 1
    for j, (mat, shape, r, q, x, y, z) in enumerate(parts):
        rho = math.hypot(x, y)
        if mat != "copper" or shape != "sphere" or rho - R - r > 0.1 * r or q <= 0:
            continue
        n = (x / rho, y / rho)
        px, py, pz = R * n[0], R * n[1], z  # contact point
        e_app = q / ((2.0 / 3.0) * math.pi ** 3 * EPS0 * r * r)
        de = 0.0
        for k, (_, _, rk, qk, xk, yk, zk) in enumerate(parts):
            if k == j or qk == 0:
                continue
            rk_xy = math.hypot(xk, yk)
            h = rk_xy - R
            if h > 0.02:  # farther than 2 cm from the drum: its dipole field at the contact is negligible
                continue
            nk = (xk / rk_xy, yk / rk_xy)
            for (cx, cy, cz, cq) in ((xk, yk, zk, qk), (xk - 2 * h * nk[0], yk - 2 * h * nk[1], zk, -qk)):
                dx, dy, dz = px - cx, py - cy, pz - cz
                d3 = (dx * dx + dy * dy + dz * dz) ** 1.5
                de += K * cq * (dx * n[0] + dy * n[1]) / d3
        ratios.append(de / e_app)
    return ratios, near, W


def main():
    pooled = []
    for run in sys.argv[1:]:
        ratios, near, W = measure(run)
        pooled += ratios
        if not ratios:
            print("%s: no copper sphere on the drum" % run)
            continue
        m = sum(ratios) / len(ratios)
        s = math.sqrt(sum((x - m) ** 2 for x in ratios) / max(1, len(ratios) - 1))
        print("%s: %d copper spheres on the drum, dE/E_applied mean %.4f, s.d. %.4f, min %.4f, max %.4f; "
              "%d particles within 2 mm of the drum (width %.0f mm)" %
              (run, len(ratios), m, s, min(ratios), max(ratios), near, W * 1e3))
    if len(sys.argv) > 2 and pooled:
        p = sorted(pooled)
        print("pooled: %d copper spheres, dE/E_applied mean %.4f, median %.4f, 90th percentile %.4f" %
              (len(p), sum(p) / len(p), p[len(p) // 2], p[int(0.9 * (len(p) - 1))]))


if __name__ == "__main__":
    main()
