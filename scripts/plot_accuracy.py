#!/usr/bin/env python3
"""Work-precision plots of `dvisim bench accuracy` (bench/accuracy/bench_accuracy.cpp), run by it after the benchmark.

    python3 plot_accuracy.py DIR        reads DIR/accuracy.csv, writes DIR/accuracy.png
    python3 plot_accuracy.py --out PNG A.csv B.csv ...
                                        one plot of several runs' rows (a full run split with --scenes/--engines,
                                        e.g. the recorded bench/results/accuracy_*.csv of one device)

One row of panels per scene; columns: CCP residual, observable error, max penetration, each against wall time,
log-log, one line per engine and solver over the iteration sweep (the time-step sweep as hollow markers).
Bullet's sequential impulse is a line too (no CCP residual).
"""
import csv
import os
import sys

from plot_common import fl, plt


def main():
    args = sys.argv[1:]
    if args and args[0] == "--out":
        if len(args) < 3:
            print("plot_accuracy.py: usage: --out PNG CSV [CSV ...]", file=sys.stderr)
            return 2
        png, files = args[1], args[2:]
    else:
        d = args[0] if args else "."
        png, files = os.path.join(d, "accuracy.png"), [os.path.join(d, "accuracy.csv")]
    rows = []
    for name in files:
        with open(name) as f:
            rows += [r for r in csv.DictReader(f) if r["status"] == "ok" and r["sweep"] != "reference"]
    if not rows:
        print("plot_accuracy.py: no measured rows in accuracy.csv")
        return 1
    scenes = []
    for r in rows:
        if r["scene"] not in scenes:
            scenes.append(r["scene"])
    metrics = [("residual_mean", "CCP residual (m/s)"), ("observable_err_rel", "observable error (rel.)"),
               ("max_penetration_rel", "max penetration (rel.)")]
    fig, axes = plt.subplots(len(scenes), len(metrics), figsize=(15, 4.2 * len(scenes)), squeeze=False)
    colors = {"jacobi": "tab:blue", "gs": "tab:purple", "apgd": "tab:green", "bb": "tab:red", "bullet-si": "tab:orange"}
    for i, scene in enumerate(scenes):
        for j, (key, label) in enumerate(metrics):
            ax = axes[i][j]
            series = {}
            for r in rows:
                if r["scene"] != scene:
                    continue
                x, y = fl(r["wall_s"]), fl(r[key])
                if x is None or y is None or x <= 0 or y <= 0:
                    continue
                series.setdefault((r["engine"], r["solver"], r["sweep"]), []).append((x, y, int(r["iterations"])))
            for (engine, solver, sweep), pts in sorted(series.items()):
                pts.sort()
                style = "-" if engine != "gpu" else "--"
                if sweep == "iterations":
                    ax.plot([p[0] for p in pts], [p[1] for p in pts], style, marker="o", ms=4,
                            color=colors.get(solver, "k"), label="%s %s" % (engine, solver))
                else:
                    ax.plot([p[0] for p in pts], [p[1] for p in pts], linestyle="none", marker="s", ms=6,
                            mfc="none", color=colors.get(solver, "k"))
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlabel("wall time (s)")
            ax.set_ylabel(label)
            ax.set_title("%s: %s" % (scene, label))
            ax.grid(True, which="both", lw=0.3)
            if j == 0 and i == 0:
                ax.legend(fontsize=7)
            if j == 1:
                ax.legend(fontsize=7)
    fig.suptitle("dvisim bench accuracy: error against wall time (lines: iteration sweep at h0; squares: step sweep)")
    fig.tight_layout()
    fig.savefig(png, dpi=90)
    print("wrote", png)
    return 0


if __name__ == "__main__":
    sys.exit(main())
