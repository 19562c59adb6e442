"""The CES machine (corona electrostatic separator, docs/CES.md) from Python.

run() is `dvisim run` on a CES document: the same code (apps/dvisim/ces_run.h, runCesMachine) writes the same
outputs, read back here, so its numbers are the CLI's bit for bit. sweep() is `dvisim sweep`'s design (full
factorial grid, seeds 1..N, the seed under the key `seed`) and its statistics (mean and Student-t 95% half-width,
apps/dvisim/sweep.h), run case by case in this process.
"""

import itertools
import json
import os
import shutil
import tempfile

import numpy as np

from . import _dvisim
from . import _override_list, _text, InputError

TABLES = {"particles": "ces_particles.csv", "collected": "ces_collected.csv", "splitters": "ces_splitters.csv",
          "distribution": "ces_distribution.csv", "grade_recovery": "ces_grade_recovery.csv"}


class CesResult:
    """A CES run: summary (dict, summary.json), metrics (dict name -> number, summary["ces"]["metrics"]), tables
    (numpy structured arrays: particles, collected, splitters (the splitter map), distribution, grade_recovery;
    pandas.DataFrame(result.particles) reads one), out (the results folder, or None when it was temporary)."""

    def __init__(self, summary, tables, out):
        self.summary = summary
        self.metrics = dict(summary.get("ces", {}).get("metrics", {}))
        self.tables = tables
        self.out = out
        for k, v in tables.items():
            setattr(self, k, v)

    def __repr__(self):
        return f"<dvisim.ces.CesResult {self.summary.get('status')}, {len(self.metrics)} metrics>"


def _read_table(path):
    if not os.path.exists(path):
        return None
    a = np.genfromtxt(path, delimiter=",", names=True, dtype=None, encoding="utf-8")
    return np.atleast_1d(a)


def _number_text(v, what, integer=False):
    if v is None:
        return ""
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
        raise InputError(f"{what}: expected a number, got {v!r}")
    if integer and not float(v).is_integer():
        raise InputError(f"{what}: expected an integer, got {v!r}")
    return str(int(v)) if integer else _text(float(v))


def _sets(overrides, seed, plots):
    sets = _override_list(overrides)
    keys = [s.split("=", 1)[0].strip() for s in sets]
    bare = [k[4:] if k.startswith("ces.") else k for k in keys]
    if seed is not None:
        if "seed" in bare:
            raise InputError("seed: given both as seed= and in overrides")
        sets.append("seed=" + _number_text(seed, "seed", integer=True))
    if not plots and "output.plots" not in bare:
        sets.append("output.plots=false")
    return sets


def run(overrides=None, duration=None, backend="auto", seed=None, scene=None, steps=None, dt=None, threads=None,
        out=None, plots=False):
    """Runs the CES machine (scene: a .json with "ces"; default: the embedded machine) and returns a CesResult.

    overrides: {key: value} relative to "ces" (`dvisim run --set`), e.g. {"electrode.voltage_kV": -30};
    duration (s) or steps; seed: the feeder's seed (ces.seed); backend auto|cpu|gpu; threads (0: OpenMP's
    default); out: keep the results there (default: a temporary folder, removed after reading);
    plots: write the per-run plots (needs matplotlib)."""
    if duration is not None and steps is not None:
        raise InputError("duration and steps are mutually exclusive")
    if not isinstance(backend, str):
        raise InputError(f"backend: expected auto, cpu or gpu, got {backend!r}")
    sets = _sets(overrides, seed, plots)
    folder = tempfile.mkdtemp(prefix="dvisim-ces-") if out is None else os.fspath(out)
    try:
        target = os.path.join(folder, "run") if out is None else folder
        _dvisim._run_ces("" if scene is None else os.fspath(scene), sets, backend,
                         _number_text(duration, "duration"), _number_text(steps, "steps", integer=True),
                         _number_text(dt, "dt"), _number_text(threads, "threads", integer=True), target)
        with open(os.path.join(target, "summary.json"), encoding="utf-8") as f:
            summary = json.load(f)
        tables = {k: _read_table(os.path.join(target, v)) for k, v in TABLES.items()}
        return CesResult(summary, tables, None if out is None else target)
    finally:
        if out is None:
            shutil.rmtree(folder, ignore_errors=True)


def mean_ci(values):
    """(n, mean, 95% confidence half-width) of `values`: t_{0.975, n-1} s / sqrt(n), as `dvisim sweep`'s
    summary.csv (NaN half-width for n < 2)."""
    return _dvisim._mean_ci([float(v) for v in values])


def grid_levels(spec):
    """The levels of a `dvisim sweep --grid` spec "KEY=v1,v2" or "KEY=lo:hi:n": (key, [level texts])."""
    return _dvisim._parse_grid(spec)


def sweep(grid, seeds=1, overrides=None, duration=None, backend="auto", steps=None, dt=None, threads=None,
          scene=None, out=None):
    """A full-factorial sweep of the CES machine with replicate seeds 1..seeds, as `dvisim sweep`.

    grid: {key: [levels]} (or {key: "lo:hi:n"}); the first key varies slowest. Returns a dict:
      "cases":   [{"id", "setting" (index), "values" ({key: level}), "seed", "metrics" (dict)}] in run order
      "summary": [{"setting", "values", "n", "<metric>": (mean, ci95) ...}] per setting, as summary.csv
      "paired":  [{"setting", "values", "n", "<metric>": (mean difference, ci95) ...}] per setting after the
                 first, its difference from setting 0 seed by seed (common random numbers), as paired.csv
    out: keep each run in out/runs/<case id> (default: temporary)."""
    if not isinstance(grid, dict) or not grid:
        raise InputError("sweep: grid must be a non-empty dict {key: [levels]}")
    if isinstance(seeds, bool) or not isinstance(seeds, (int, np.integer)) or seeds < 1:
        raise InputError(f"sweep: seeds must be an integer >= 1, got {seeds!r}")
    factors = []
    for key, levels in grid.items():
        spec = f"{key}={levels}" if isinstance(levels, str) else f"{key}=" + ",".join(_text(v) for v in levels)
        factors.append(grid_levels(spec))
    settings = [dict(zip([k for k, _ in factors], combo)) for combo in itertools.product(*[v for _, v in factors])]
    fixed = dict(overrides or {})
    cases = []
    for i, values in enumerate(settings):
        for seed in range(1, int(seeds) + 1):
            cid = _dvisim._case_id(i, len(settings), seed)
            case_out = None if out is None else os.path.join(os.fspath(out), "runs", cid)
            sets = _override_list(fixed) + [f"{k}={v}" for k, v in values.items()]
            r = run(sets, duration=duration, backend=backend, seed=seed, scene=scene, steps=steps, dt=dt,
                    threads=threads, out=case_out)
            cases.append({"id": cid, "setting": i, "values": values, "seed": seed, "metrics": r.metrics,
                          "_numbers": _dvisim._run_metrics(json.dumps(r.summary))})
    summary = []
    for i, values in enumerate(settings):
        rows = [c["_numbers"] for c in cases if c["setting"] == i]  # sweep.h: runMetrics, numbers only
        entry = {"setting": i, "values": values, "n": len(rows)}
        for name in sorted({k for r in cases for k in r["_numbers"]}):
            _, mean, half = mean_ci([r[name] for r in rows if name in r])
            entry[name] = (mean, half)
        summary.append(entry)
    # against setting 0, seed by seed (common random numbers; sweep.h: pairedDifference), as paired.csv
    names = sorted({k for c in cases for k in c["_numbers"]})
    by = [{n: {c["seed"]: c["_numbers"][n] for c in cases if c["setting"] == i and n in c["_numbers"]}
           for n in names} for i in range(len(settings))]
    paired = []
    for i in range(1, len(settings)):
        entry = {"setting": i, "values": settings[i]}
        diffs = {n: _dvisim._paired_difference(by[0][n], by[i][n]) for n in names}
        entry["n"] = max((d[0] for d in diffs.values()), default=0)
        entry.update({n: (d[1], d[2]) for n, d in diffs.items()})
        paired.append(entry)
    for c in cases:
        del c["_numbers"]
    return {"cases": cases, "summary": summary, "paired": paired}
