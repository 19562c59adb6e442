"""A pile of spheres poured into a box, settled, and its height profile plotted (docs/PYTHON.md).

    PYTHONPATH=build/python python3 examples/python/pile_height_profile.py [--n 4000] [--steps 600] [--out DIR]
    --quick: 500 spheres, 60 steps (the test suite's run)

Writes pile_height_profile.png (mean and maximum top height of the spheres in bins along x) and prints the mean
height. The state is read straight from the engine's arrays (System.positions is a view, no copy).
"""

import argparse
import os

import numpy as np

import dvisim


def build(n, radius=0.01, seed=1):
    sim = dvisim.System(backend="auto", dt=1e-3)
    width = 0.3
    sim.add_body(dvisim.Plane((0, 1, 0), 0.0), fixed=True)  # the ground
    for centre, half in (((-0.01, 0.3, width / 2), (0.01, 0.3, width / 2)),  # four walls
                         ((width + 0.01, 0.3, width / 2), (0.01, 0.3, width / 2)),
                         ((width / 2, 0.3, -0.01), (width / 2, 0.3, 0.01)),
                         ((width / 2, 0.3, width + 0.01), (width / 2, 0.3, 0.01))):
        sim.add_body(dvisim.Box(half), position=centre, fixed=True)
    # a loose lattice in the left third of the box: it slumps to the right as it settles
    per_row = int(width / 3 / (2.2 * radius)), int(width / (2.2 * radius))
    rng = np.random.default_rng(seed)
    k = np.arange(n)
    x = (k % per_row[0]) * 2.2 * radius + radius * 1.1
    z = ((k // per_row[0]) % per_row[1]) * 2.2 * radius + radius * 1.1
    y = (k // (per_row[0] * per_row[1])) * 2.2 * radius + radius * 1.1
    pos = np.column_stack([x, y, z]) + rng.uniform(-0.05, 0.05, (n, 3)) * radius
    ids = sim.add_spheres(pos, radius, density=2500, friction=0.5)
    return sim, ids, width, radius


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=4000)
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--out", default=".")
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args()
    if a.quick:
        a.n, a.steps = 500, 60
    sim, ids, width, r = build(a.n)
    sim.step(a.steps)
    p = sim.positions[ids]  # (n, 3), the engine's memory
    bins = np.linspace(0, width, 16)
    which = np.clip(np.digitize(p[:, 0], bins) - 1, 0, len(bins) - 2)
    top = p[:, 1] + r
    mean_h = np.array([top[which == b].mean() if np.any(which == b) else 0 for b in range(len(bins) - 1)])
    max_h = np.array([top[which == b].max() if np.any(which == b) else 0 for b in range(len(bins) - 1)])
    print(f"{sim.body_count} bodies on {sim.backend}, {sim.step_count} steps: mean height {top.mean():.4f} m, "
          f"{sim.summary()['ms_per_step']:.2f} ms/step")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    centres = 0.5 * (bins[1:] + bins[:-1])
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(centres, max_h, "o-", label="highest sphere top")
    ax.plot(centres, mean_h, "s-", label="mean sphere top")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("height [m]")
    ax.set_title(f"pile of {a.n} spheres after {a.steps} steps")
    ax.legend()
    fig.tight_layout()
    path = os.path.join(a.out, "pile_height_profile.png")
    fig.savefig(path, dpi=120)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
