#!/usr/bin/env python3
"""Plots of `dvisim bench scaling` (bench/scaling/bench_scaling.cpp), run by it after the benchmark.

    python3 plot_scaling.py DIR        reads DIR/scaling.csv, writes DIR/scaling.png

Left: ms per step against N, log-log, one line per engine and scene. Right: the stage breakdown
(broad, narrow, solve, integrate, other) of the GPU rows as shares of the step, one bar per scene
and N (the CPU backend's rows when no GPU row ran).
"""
import csv
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def label_n(n):
    if n >= 1000000 and n % 1000000 == 0:
        return "%dM" % (n // 1000000)
    if n >= 1000 and n % 1000 == 0:
        return "%dk" % (n // 1000)
    return str(n)


def main():
    d = sys.argv[1] if len(sys.argv) > 1 else "."
    with open(os.path.join(d, "scaling.csv")) as f:
        rows = [r for r in csv.DictReader(f) if r["status"] == "ok" and r["ms_per_step"]]
    if not rows:
        print("plot_scaling.py: no measured rows in scaling.csv")
        return 1
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 5.2))
    colors = {"gpu": "tab:green", "cpu": "tab:blue", "bullet": "tab:orange"}
    styles = {"pile": "-", "mix": "--"}
    markers = {"pile": "o", "mix": "s"}
    series = {}
    for r in rows:
        series.setdefault((r["engine"], r["scene"]), []).append((int(r["n"]), float(r["ms_per_step"])))
    for (engine, scene), pts in sorted(series.items()):
        pts.sort()
        ax.plot([p[0] for p in pts], [p[1] for p in pts], color=colors.get(engine), linestyle=styles.get(scene, ":"),
                marker=markers.get(scene, "^"), label="%s %s" % (engine, scene))
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("bodies N")
    ax.set_ylabel("ms per step")
    ax.axhline(20, color="grey", lw=0.8, ls="-.")
    ax.text(ax.get_xlim()[0], 20, " goal: 1M at 20 ms", fontsize=7, va="bottom", color="grey")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("time step (h = 1e-3 s, APGD 50 it.; Bullet SI 10 it., 1 thread)", fontsize=9)

    engine = "gpu" if any(r["engine"] == "gpu" for r in rows) else "cpu"
    stage_rows = [r for r in rows if r["engine"] == engine and r["ms_broad"]]
    stage_rows.sort(key=lambda r: (r["scene"], int(r["n"])))
    stages = [("ms_broad", "broad"), ("ms_narrow", "narrow"), ("ms_solve", "solve"),
              ("ms_integrate", "integrate"), ("ms_other", "other")]
    x = list(range(len(stage_rows)))
    bottom = [0.0] * len(stage_rows)
    totals = [sum(float(r[k] or 0) for k, _ in stages) or 1.0 for r in stage_rows]
    for key, name in stages:
        vals = [100.0 * float(r[key] or 0) / t for r, t in zip(stage_rows, totals)]
        bx.bar(x, vals, bottom=bottom, label=name)
        bottom = [b + v for b, v in zip(bottom, vals)]
    for i, r in enumerate(stage_rows):
        text = "%.3g ms" % float(r["ms_per_step"])
        if r["solve_pct_of_copy"]:
            text += "\nBW %.0f%%" % float(r["solve_pct_of_copy"])
        bx.text(i, 101, text, ha="center", va="bottom", fontsize=7)
    bx.set_xticks(x)
    bx.set_xticklabels(["%s\n%s" % (r["scene"], label_n(int(r["n"]))) for r in stage_rows], fontsize=8)
    bx.set_ylim(0, 118)
    bx.set_ylabel("% of the step")
    bx.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=5)
    bx.set_title("%s stages (above: ms/step; solver bandwidth as %% of the measured copy)" % engine.upper(), fontsize=9)
    fig.tight_layout()
    fig.savefig(os.path.join(d, "scaling.png"), dpi=120)
    return 0


if __name__ == "__main__":
    sys.exit(main())
