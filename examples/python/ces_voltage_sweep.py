"""The CES machine over electrode voltages with replicate seeds: grade and recovery of the conductor and
nonconductor products with 95% confidence intervals, as `dvisim sweep` computes them (docs/PYTHON.md, docs/CES.md).

    PYTHONPATH=build/python python3 examples/python/ces_voltage_sweep.py [--duration 2] [--seeds 3] [--out DIR]
    --quick: two voltages, one seed, 0.05 s of machine time (the test suite's run)

Writes ces_voltage_sweep.png and ces_voltage_sweep.csv (per voltage: mean and half-width of each metric; pandas
reads it, or pandas.DataFrame(result["summary"]) directly).
"""

import argparse
import csv
import os

import dvisim

METRICS = ["fixed.conductor.grade", "fixed.conductor.recovery", "fixed.nonconductor.grade",
           "fixed.nonconductor.recovery"]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--voltages", default="-20,-30,-40")
    ap.add_argument("--duration", type=float, default=2.0)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--backend", default="auto")
    ap.add_argument("--out", default=".")
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args()
    if a.quick:
        a.voltages, a.duration, a.seeds = "-20,-40", 0.05, 1
    volts = [float(v) for v in a.voltages.split(",")]
    res = dvisim.ces.sweep({"electrode.voltage_kV": volts}, seeds=a.seeds, duration=a.duration, backend=a.backend)
    rows = res["summary"]
    with open(os.path.join(a.out, "ces_voltage_sweep.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["voltage_kV", "n"] + [f"{m}.{s}" for m in METRICS for s in ("mean", "ci95")])
        for r in rows:
            w.writerow([r["values"]["electrode.voltage_kV"], r["n"]] + [x for m in METRICS for x in r.get(m, ("", ""))])
    for r in rows:
        g = r.get("fixed.conductor.grade", (float("nan"),) * 2)
        print(f"U = {r['values']['electrode.voltage_kV']} kV: conductor grade {g[0]:.3f} +- {g[1]:.3f} (n = {r['n']})")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.5))
    for ax, what in zip(axes, ("grade", "recovery")):
        for product in ("conductor", "nonconductor"):
            key = f"fixed.{product}.{what}"
            mean = [r.get(key, (float("nan"), 0))[0] for r in rows]
            half = [r.get(key, (0, float("nan")))[1] for r in rows]
            half = [0 if h != h else h for h in half]  # NaN (one seed): no bar
            ax.errorbar(volts, mean, yerr=half, marker="o", capsize=3, label=product)
        ax.set_xlabel("electrode voltage [kV]")
        ax.set_ylabel(what + " (fixed splitters)")
        ax.legend()
    fig.suptitle(f"CES machine, {a.duration:g} s, {a.seeds} seed(s) per voltage")
    fig.tight_layout()
    path = os.path.join(a.out, "ces_voltage_sweep.png")
    fig.savefig(path, dpi=120)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
