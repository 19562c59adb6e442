#!/usr/bin/env python3
"""Plots of `dvisim sweep` (apps/dvisim/sweep.cpp), run by it after the sweep.

    python3 plot_sweep.py DIR        reads DIR/sweep.json and DIR/summary.csv, writes DIR/sweep_<key>.png

One figure per swept key: a panel per grade or recovery metric (every summary.csv metric whose name contains
"grade" or "recovery"), the mean against the key's levels with the 95% confidence half-width as error bars,
one line per combination of the other swept keys' levels.
"""
import csv
import json
import os
import re
import sys

from plot_common import fl, plt


def level_axis(values):
    """Positions of the levels: the numbers themselves when all are numeric, else their order (categorical)."""
    if all(fl(v) is not None for v in values):
        return {v: fl(v) for v in values}, None
    order = sorted(set(values), key=values.index)
    return {v: i for i, v in enumerate(order)}, order


def plot_key(out_dir, key, keys, rows, metrics):
    others = [k for k in keys if k != key]
    pos, categories = level_axis([r[key] for r in rows])
    ncol = min(4, len(metrics))
    nrow = (len(metrics) + ncol - 1) // ncol
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.4 * nrow), squeeze=False)
    groups = {}
    for r in rows:
        groups.setdefault(tuple(r[k] for k in others), []).append(r)
    for ax, m in zip(axes.flat, metrics):
        for label, grp in groups.items():
            pts = sorted((pos[r[key]], fl(r[m + ".mean"]), fl(r[m + ".ci95"]) or 0.0) for r in grp if fl(r[m + ".mean"]) is not None)
            if not pts:
                continue
            name = ", ".join(f"{k}={v}" for k, v in zip(others, label)) or "mean"
            ax.errorbar([p[0] for p in pts], [p[1] for p in pts], yerr=[p[2] for p in pts], marker="o", capsize=3, label=name)
        ax.set_title(m, fontsize=9)
        ax.set_xlabel(key)
        if categories:
            ax.set_xticks(range(len(categories)))
            ax.set_xticklabels(categories)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(metrics):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7)
    fig.suptitle(f"sweep over {key}: mean and 95% confidence interval (n per point in summary.csv)", fontsize=10)
    fig.tight_layout()
    png = os.path.join(out_dir, "sweep_" + re.sub(r"[^A-Za-z0-9_.-]", "_", key) + ".png")
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return png


def main():
    if len(sys.argv) != 2:
        sys.exit("usage: plot_sweep.py DIR")
    out_dir = sys.argv[1]
    with open(os.path.join(out_dir, "sweep.json")) as f:
        keys = json.load(f)["keys"]
    with open(os.path.join(out_dir, "summary.csv"), newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        sys.exit("summary.csv has no settings")
    metrics = [c[: -len(".mean")] for c in rows[0] if c.endswith(".mean") and re.search("grade|recovery", c)]
    if not metrics:
        print("no grade or recovery metric in summary.csv: nothing to plot")
        return
    for key in keys:
        print(plot_key(out_dir, key, keys, rows, metrics))


if __name__ == "__main__":
    main()
