#!/usr/bin/env python3
"""One table per benchmark kind from the records in bench/results/.

    python3 scripts/results_table.py > bench/RESULTS.md     regenerate bench/RESULTS.md
    python3 scripts/results_table.py --check                exit 1 when bench/RESULTS.md is stale

Every bench/results/<kind>_<device>_<date>.md is written by `dvisim bench <kind> --record`
(bench/<kind>/bench_<kind>.cpp). This script reads those .md files only (device, commit, date and
the headline numbers each one prints) and writes one markdown table per kind, newest run first.
A number a record does not carry (a scene that did not run, an older record's format) prints "-".
Nothing here is typed by hand: to change bench/RESULTS.md, record a run and regenerate.
"""
import os
import re
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RESULTS_DIR = os.path.join(ROOT, "bench", "results")
RESULTS_MD = os.path.join(ROOT, "bench", "RESULTS.md")

KINDS = ["scaling", "scaling_mpi", "ces", "accuracy", "pruning", "stability", "dropin", "dropincorpus"]
DASH = "-"


def field(text, name):
    """The value of a '- name: value' line, or None."""
    m = re.search(r"^- " + re.escape(name) + r": (.*)$", text, re.M)
    return m.group(1).strip() if m else None


def line_group(pattern, text):
    """The first group of pattern's first match in text, with ^ and $ at every line (re.M); None without one."""
    m = re.search(pattern, text, re.M)
    return m.group(1) if m else None


def short_device(s):
    """'NVIDIA H200 (143155 MiB, sm_90)' -> 'NVIDIA H200'; CPU names keep their thread count."""
    if not s:
        return None
    if re.search(r"MiB|sm_\d", s):
        s = re.sub(r"\s*\([^)]*\)\s*$", "", s)
    return s.strip()


def short_commit(s):
    """7 hex digits; a '+' marks a record made from a working tree with uncommitted changes."""
    if not s:
        return None
    m = re.match(r"([0-9a-fA-F]{7,40})", s)
    if not m:
        return s
    return m.group(1)[:7] + ("+" if "uncommitted" in s else "")


def short_date(s):
    """'2026-11-25T13:24:31Z' -> '2026-11-25 13:24'."""
    if not s:
        return None
    m = re.match(r"(\d{4}-\d\d-\d\d)T(\d\d:\d\d)", s)
    return "%s %s" % (m.group(1), m.group(2)) if m else s


def common(text, device_names=("device", "GPU")):
    dev = None
    for name in device_names:
        v = field(text, name)
        if v and not v.startswith("skipped"):
            dev = short_device(v)
            break
    if dev is None:
        cpu = field(text, "host CPU")
        if cpu:
            dev = cpu + ", no GPU"
    return {
        "date": field(text, "date"),
        "device": dev,
        "commit": short_commit(field(text, "commit")),
    }


# --- scaling ---------------------------------------------------------------------------------
SCALING_N = ["10k", "100k", "1M", "4M"]


def scaling_rows(text):
    """{(engine, scene, N): [columns...]} from the fixed-width table of a scaling record."""
    rows = {}
    m = re.search(r"^```\n(.*?)^```", text, re.M | re.S)
    if not m:
        return rows
    header = None
    for line in m.group(1).splitlines():
        cols = line.split()
        if not cols:
            continue
        if cols[0] == "engine":
            header = line
            continue
        if header is None or len(cols) < 4:
            continue
        rows[(cols[0], cols[1], cols[2])] = cols[3:]
    return rows


def scaling_value(rows, engine, scene, n, index):
    """Column `index` after N (0 = ms/step, ..., -1 = %copy) when the row was measured."""
    cols = rows.get((engine, scene, n))
    if not cols or len(cols) < 10:
        return None
    try:
        float(cols[0])
    except ValueError:  # "skipped: ...", "error: ...", "not run: ..."
        return None
    v = cols[index]
    return None if v == "-" else v


def scaling(text):
    rows = scaling_rows(text)
    r = common(text)
    for n in SCALING_N:
        r["gpu pile " + n] = scaling_value(rows, "gpu", "pile", n, 0)
    r["%copy"] = scaling_value(rows, "gpu", "pile", "1M", -1)
    r["gpu mix 1M"] = scaling_value(rows, "gpu", "mix", "1M", 0)
    r["mix 1M contacts"] = scaling_value(rows, "gpu", "mix", "1M", 5)
    r["cpu pile 100k"] = scaling_value(rows, "cpu", "pile", "100k", 0)
    r["bullet pile 100k"] = scaling_value(rows, "bullet", "pile", "100k", 0)
    return r


SCALING_COLS = [
    ("date", "date"), ("device", "device"), ("commit", "commit"),
    ("gpu pile 10k", "GPU pile 10k"), ("gpu pile 100k", "100k"), ("gpu pile 1M", "1M"),
    ("gpu pile 4M", "4M"), ("%copy", "%copy 1M"), ("gpu mix 1M", "GPU mix 1M"),
    ("mix 1M contacts", "mix 1M contacts"),
    ("cpu pile 100k", "CPU pile 100k"), ("bullet pile 100k", "Bullet pile 100k"),
]
SCALING_INTRO = (
    "Sphere pile and multidisperse mix, h = 1 ms, APGD 50 iterations. Times are ms/step (wall time "
    "of step()); %copy is the GPU solver's modelled bandwidth at the 1M pile as a share of the copy "
    "bandwidth measured in the same run. The mix's contact count tells its versions apart: rows with "
    "different counts ran different scenes. CPU is our CPU backend on the host's threads, Bullet is "
    "Bullet 2 on one thread; both run on the host CPU of the named machine."
)


# --- ces -------------------------------------------------------------------------------------
def table_value(text, quantity):
    m = re.search(r"^\| " + re.escape(quantity) + r" \| (.*?) \|\s*$", text, re.M)
    return m.group(1).strip() if m else None


# The CES columns read from a row of the record's table: (column, row, re.match or re.search, the pattern whose first
# group is the value, whether the row's whole text stands in when the pattern does not match).
CES_TABLE_VALUES = [
    ("machine time", "machine time reached", re.match, r"([\d.]+ s of [\d.]+ s)", True),
    ("wall", "wall time", re.match, r"([\d.]+ s)", True),
    ("particles/s", "particles fed", re.search, r"\(([\d,]+) particles/s", False),
    ("ms/step", "ms/step", re.match, r"([\d.]+) mean", False),
    ("in flight", "bodies in flight", re.match, r"([\d,]+) max", False),
    ("contacts", "contacts per step", re.match, r"([\d,]+) mean", False),
]


def ces(text):
    r = common(text)
    backend = field(text, "backend")
    if backend:
        m = re.match(r"(\w+)\s*(?:\((.*)\))?", backend)
        b = m.group(1)
        detail = m.group(2) or ""
        if "on the device" in detail:
            b += ", CES on device"
        elif "host" in detail:
            b += ", CES on host"
        r["backend"] = b
    goal = re.search(r"^\*\*(.*)\*\*\s*$", text, re.M)
    if goal:
        g = goal.group(1)
        m = re.search(r":\s*(met|missed)\b( by ~?[\d.]+x)?", g)
        if m:
            r["goal"] = m.group(1) + (m.group(2) or "")
        elif g.startswith("no verdict"):
            w = re.search(r"--wall-limit ([\d.]+ s)", g)
            r["goal"] = "no verdict (wall limit %s)" % w.group(1) if w else "no verdict"
    for col, row, find, pattern, keep in CES_TABLE_VALUES:
        value = table_value(text, row)
        if value:
            m = find(pattern, value)
            r[col] = m.group(1) if m else (value if keep else None)
    r["narrow share"] = line_group(r"^\| NarrowPhase \| [\d.]+ \| ([\d.]+%) \|", text)
    return r


CES_COLS = [
    ("date", "date"), ("device", "device"), ("commit", "commit"), ("backend", "backend"),
    ("goal", "goal"), ("machine time", "machine time"), ("wall", "wall"),
    ("particles/s", "particles/s fed"), ("ms/step", "ms/step (mean)"),
    ("in flight", "bodies in flight (max)"), ("contacts", "contacts/step (mean)"),
    ("narrow share", "NarrowPhase share"),
]
CES_INTRO = (
    "The default CES machine fed 0.5-1 mm particles at 20,000 particles/s; the goal is 10 s of "
    "machine time in at most 300 s wall. A run that misses stops at the wall limit, so its machine "
    "time is short of 10 s."
)


# --- accuracy --------------------------------------------------------------------------------
def accuracy(text):
    r = common(text)
    m = re.search(r"^- this run: (.*)$", text, re.M)
    r["this run"] = "; ".join(
        "%s %s" % p for p in re.findall(r"--(\w+) (\S+)", m.group(1))) if m else None
    for engine in ("gpu", "cpu"):
        g = re.search(
            r"^\s*" + engine + r", warm start: APGD (\d+) it, ([\d.e+-]+) s .*?; Jacobi (\d+) it, "
            r"([\d.e+-]+) s .*?: ratio (>= )?([\d.]+)x", text, re.M)
        if g:
            r[engine + " apgd"] = "%s it, %s s" % (g.group(1), g.group(2))
            r[engine + " ratio"] = (">= " if g.group(5) else "") + g.group(6) + "x"
    return r


ACCURACY_COLS = [
    ("date", "date"), ("device", "device"), ("commit", "commit"), ("this run", "this run"),
    ("gpu apgd", "GPU APGD to 1e-4"), ("gpu ratio", "GPU Jacobi/APGD time"),
    ("cpu apgd", "CPU APGD to 1e-4"), ("cpu ratio", "CPU Jacobi/APGD time"),
]
ACCURACY_INTRO = (
    "Time for one CCP solve to reach residual 1e-4 on the 100,000-sphere pile, warm start, APGD "
    "against Jacobi from the same state (Jacobi capped at 5000 iterations, so a '>=' ratio means "
    "Jacobi did not reach the tolerance). Runs that recorded other scenes only (\"this run\") carry "
    "their rows in the CSV beside the record and show \"-\" here."
)


# --- pruning ---------------------------------------------------------------------------------
def pruning(text):
    r = common(text)
    m = re.search(r"^- scene: pile of (\d+) spheres", text, re.M)
    if m:
        n = int(m.group(1))
        r["N"] = ("%dM" % (n // 1000000)) if n % 1000000 == 0 else (
            ("%dk" % (n // 1000)) if n % 1000 == 0 else str(n))
    for scene in ("frictionless", "frictional"):
        for prune in ("true", "false"):
            r["%s %s" % (scene, prune)] = line_group(
                r"^\| pile-" + scene + r" \| " + prune + r" \| ([\d.]+) \|", text)
    r["saving frictionless"] = line_group(r"^- frictionless pile: ([\d.]+%)", text)
    r["saving frictional"] = line_group(r"^- frictional pile[^:]*: ([\d.]+%)", text)
    return r


PRUNING_COLS = [
    ("date", "date"), ("device", "device"), ("commit", "commit"), ("N", "spheres"),
    ("frictionless true", "frictionless pruned"), ("frictionless false", "frictionless full"),
    ("saving frictionless", "saving"),
    ("frictional true", "frictional pruned"), ("frictional false", "frictional full"),
    ("saving frictional", "saving (control)"),
]
PRUNING_INTRO = (
    "ms/step of a sphere pile with the stages it does not need left out (pruned) and with every "
    "stage (full), measured side by side in the same run; the frictional pile is the control, "
    "where every contact needs its friction rows."
)


# --- stability -------------------------------------------------------------------------------
def stability(text):
    r = common(text)
    m = re.search(r"^Summary: our engine passes (\d+) of (\d+) runs(?:; Bullet passes (\d+) of (\d+))?",
                  text, re.M)
    if m:
        r["ours"] = "%s/%s" % (m.group(1), m.group(2))
        if m.group(3):
            r["bullet"] = "%s/%s" % (m.group(3), m.group(4))
    cases = re.findall(r"^\| ([^|\s]+) \| (?:cpu|gpu|bullet\w*) \|", text, re.M)
    cases = [c for c in cases if c != "case"]
    if cases:
        r["cases"] = str(len(set(cases)))
    r["run time"] = line_group(r"^Total run time ([\d.]+ s)", text)
    return r


STABILITY_COLS = [
    ("date", "date"), ("device", "device"), ("commit", "commit"), ("cases", "cases"),
    ("ours", "ours passed"), ("bullet", "Bullet passed"), ("run time", "run time"),
]
STABILITY_INTRO = (
    "Stiff and extreme cases (mass ratios, tall stacks, size range, thin walls at speed, friction "
    "on an incline against its analytic answer, initial overlap); each engine's run passes or "
    "fails the case's criterion. Bullet counts its default 10 and 100 iterations as separate runs."
)

# --- dropin ----------------------------------------------------------------------------------
DROPIN_SCENES = ["boxes", "pyramid", "ragdolls", "hulls", "terrain", "boxes100k"]


def dropin(text):
    r = common(text, device_names=("GPU", "CPU") if field(text, "GPU") not in (None, "none") else ("CPU",))
    for scene in DROPIN_SCENES:
        for engine in ("cpu", "gpu"):
            r["%s %s" % (scene, engine)] = line_group(
                r"^\| " + scene + r" \| " + engine + r" \| [^|]*\| [^|]*\| [^|]*\| ([\d.]+x) \|", text)
    r["cpu goal"] = line_group(
        r"^Goal: our CPU drop-in at <= 1.0x Bullet's time on every scene: ([A-Z ]+ \(\d+ of \d+ scenes\))", text)
    return r


DROPIN_COLS = [("date", "date"), ("device", "device"), ("commit", "commit")] + [
    ("%s %s" % (s, e), "%s %s" % (s, e.upper())) for s in DROPIN_SCENES for e in ("cpu", "gpu")] + [
    ("cpu goal", "CPU <= 1.0x Bullet")]
DROPIN_INTRO = (
    "Bullet's benchmark scenes, our drop-in world's ms/step over stock Bullet's (btDiscreteDynamicsWorld, one "
    "thread), measured side by side in the same run: below 1.0x we are faster. The record has the absolute times, "
    "contact points, the deepest penetration and each scene's drift."
)

# --- dropincorpus ----------------------------------------------------------------------------
def dropincorpus(text):
    r = common(text, device_names=("device",))
    m = re.search(r"^Geometric mean of the ratios: ([\d.]+x) over (\d+) examples that ran \(largest ([\d.]+x)\)", text, re.M)
    if m:
        r["geomean"], r["ran"], r["largest"] = m.group(1), m.group(2), m.group(3)
    r["examples"] = str(len(re.findall(r"^\| [A-Za-z0-9]+ \| (?:runs|\*\*refused\*\*) \|", text, re.M)))
    r["failing"] = str(len(re.findall(r"^- \S+ (?:FAILS|fails) ", text, re.M)))
    r["goal"] = line_group(r"^Goal \(issue 37\).*: (MET|NOT MET)\.$", text)
    return r


DROPINCORPUS_COLS = [("date", "date"), ("device", "device"), ("commit", "commit"), ("examples", "examples"),
                     ("ran", "ran on the drop-in"), ("geomean", "ms/frame ratio, geomean"),
                     ("largest", "largest ratio"), ("failing", "checks failed (known and new)"),
                     ("goal", "speed goal")]
DROPINCORPUS_INTRO = (
    "Bullet's own example programs (bullet3 6c888f4, unchanged but for the world line) on stock Bullet and on the "
    "drop-in world at its default configuration, one thread each, 300 frames: our ms per frame over stock's in the "
    "same run. The record has every example's joint errors, body differences, pile heights, vehicle chassis and "
    "the checks of issue 37 it fails."
)

# --- scaling --mpi ---------------------------------------------------------------------------
def scaling_mpi(text):
    r = common(text, device_names=("GPU", "CPU") if field(text, "GPU") not in (None, "none") else ("CPU",))
    for mode in ("weak", "strong"):
        rows = re.findall(r"^\| " + mode + r" \| (\d+) \| (\d+) \| ([\d.]+) \| ([\d.]+|-) \|", text, re.M)
        many = [x for x in rows if x[0] != "1"]
        one = [x for x in rows if x[0] == "1"]
        r["processes"] = many[0][0] if many else r.get("processes")
        if one and many:
            r[mode + " n"] = "%s -> %s" % (one[0][1], many[0][1])
            r[mode + " ms"] = "%s -> %s" % (one[0][2], many[0][2])
            r[mode + " eff"] = many[0][3]
        elif many:  # --baseline off: the K-process run alone
            r[mode + " n"], r[mode + " ms"], r[mode + " eff"] = many[0][1], many[0][2], "-"
    return r


SCALING_MPI_COLS = [("date", "date"), ("device", "device"), ("commit", "commit"), ("processes", "processes"),
                    ("weak n", "weak spheres"), ("weak ms", "weak ms/step"), ("weak eff", "weak efficiency"),
                    ("strong n", "strong spheres"), ("strong ms", "strong ms/step"),
                    ("strong eff", "strong efficiency")]
SCALING_MPI_INTRO = (
    "The domain decomposition over MPI (`mpirun -np K dvisim bench scaling --mpi`; CPU backend, or one GPU a process "
    "with `--mpi-backend gpu`): the sphere pile on process 0 alone and on all K processes in one run, weak (N a "
    "process) and strong (the same pile); `--baseline off` runs the K processes alone (efficiency `-`). The record "
    "has the time per phase and stage, the bytes moved per step and the plain System's time on the one-process pile."
)

PARSERS = {
    "scaling": (scaling, SCALING_COLS, SCALING_INTRO, "Scaling (`dvisim bench scaling`)"),
    "scaling_mpi": (scaling_mpi, SCALING_MPI_COLS, SCALING_MPI_INTRO,
                    "Domain decomposition over MPI (`dvisim bench scaling --mpi`)"),
    "ces": (ces, CES_COLS, CES_INTRO, "CES industrial feed (`dvisim bench ces`)"),
    "accuracy": (accuracy, ACCURACY_COLS, ACCURACY_INTRO, "Accuracy (`dvisim bench accuracy`)"),
    "pruning": (pruning, PRUNING_COLS, PRUNING_INTRO, "Pruning (`dvisim bench pruning`)"),
    "stability": (stability, STABILITY_COLS, STABILITY_INTRO, "Stability (`dvisim bench stability`)"),
    "dropin": (dropin, DROPIN_COLS, DROPIN_INTRO, "Drop-in world on Bullet's scenes (`dvisim bench dropin`)"),
    "dropincorpus": (dropincorpus, DROPINCORPUS_COLS, DROPINCORPUS_INTRO,
                     "Bullet's example programs on the drop-in world (`dvisim_dropin_corpus`)"),
}


def cell(v):
    if v is None or v == "":
        return DASH
    return str(v).replace("|", "\\|")


def render(results_dir):
    records = {k: [] for k in KINDS}
    others = []
    for name in sorted(os.listdir(results_dir)):
        if not name.endswith(".md"):
            continue
        kind = "scaling_mpi" if name.startswith("scaling_mpi_") else name.split("_", 1)[0]
        if kind not in PARSERS:
            others.append(name)
            continue
        with open(os.path.join(results_dir, name), encoding="utf-8") as f:
            text = f.read()
        row = PARSERS[kind][0](text)
        row["file"] = name
        # Newest first: the record's own date, else the date stamp of its file name.
        stamp = re.search(r"_(\d{8}-\d{6})\.md$", name)
        key = row.get("date") or ""
        if not key and stamp:
            s = stamp.group(1)
            key = "%s-%s-%sT%s:%s:%sZ" % (s[:4], s[4:6], s[6:8], s[9:11], s[11:13], s[13:15])
        row["sort"] = key
        row["date"] = short_date(row.get("date"))
        records[kind].append(row)

    out = []
    out.append("# Benchmark results")
    out.append("")
    out.append("Generated by `python3 scripts/results_table.py > bench/RESULTS.md` from the records in "
               "bench/results/ (each written by `dvisim bench <kind> --record`); do not edit by hand. "
               "`python3 scripts/results_table.py --check` fails when this file is stale.")
    out.append("")
    out.append("One table per benchmark, newest run first, one row per record. Absolute times hold only "
               "for the device named in their row; compare runs of the same device. \"-\" marks a number "
               "the record does not carry. A commit ending in \"+\" was recorded from a working tree "
               "with uncommitted changes. The file name in the last column is the full record (with "
               "its CSV or JSON rows beside it).")
    for kind in KINDS:
        parse, cols, intro, title = PARSERS[kind]
        rows = sorted(records[kind], key=lambda r: r["sort"], reverse=True)
        out.append("")
        out.append("## " + title)
        out.append("")
        out.append(intro)
        out.append("")
        if not rows:
            out.append("No records.")
            continue
        heads = [h for _, h in cols] + ["record"]
        out.append("| " + " | ".join(heads) + " |")
        out.append("| " + " | ".join("---" for _ in heads) + " |")
        for r in rows:
            vals = [cell(r.get(k)) for k, _ in cols] + ["[%s](results/%s)" % (r["file"], r["file"])]
            out.append("| " + " | ".join(vals) + " |")
    if others:
        out.append("")
        out.append("Records of other kinds, not tabulated: " + ", ".join(others) + ".")
    return "\n".join(out) + "\n"


def main(argv):
    check = False
    for a in argv[1:]:
        if a == "--check":
            check = True
        elif a in ("-h", "--help"):
            print(__doc__.strip())
            return 0
        else:
            sys.stderr.write("results_table.py: unknown argument '%s' (use --check or nothing)\n" % a)
            return 2
    if not os.path.isdir(RESULTS_DIR):
        sys.stderr.write("results_table.py: no results folder at %s\n" % RESULTS_DIR)
        return 2
    text = render(RESULTS_DIR)
    if not check:
        sys.stdout.write(text)
        return 0
    try:
        with open(RESULTS_MD, encoding="utf-8") as f:
            current = f.read()
    except OSError:
        current = None
    if current != text:
        sys.stderr.write("bench/RESULTS.md is stale: run `python3 scripts/results_table.py > bench/RESULTS.md`\n")
        return 1
    print("bench/RESULTS.md is up to date")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
