#!/usr/bin/env python3
"""Checks the source layout of src/ (docs/ARCHITECTURE.md, "Source layout"): no file includes a higher layer,
and no folder holds more than 15 files.

    python3 tests/check_layout.py [SRC_DIR]      (default: the src/ next to this script's folder)
    python3 tests/check_layout.py --self-test    (the check finds each kind of violation in a made-up tree)

Layers of src/chrono_like, lowest first; a file may include its own layer and the ones it lists:
    base/       nothing else
    collision/  base/
    solver/     base/, collision/
    the files at the top of src/chrono_like (the System):  base/, collision/, solver/
    bullet/     base/, collision/, solver/, the top
    io/         base/, collision/, solver/, the top, bullet/ (a .bullet scene is read through the bridge)
    mpi/        base/, collision/, solver/, the top (the domain decomposition over MPI drives Systems)
src/gpu may include src/chrono_like; src/ces may include src/chrono_like and src/gpu; src/dvisim (the public
headers) may include all of them, and a deprecated path of FORWARDERS its public header. Nothing in src/ includes
apps/, bench/, tests/ or demos/ (nor anything else outside src/). Prints one line per violation and exits 1 when
there is any.
"""
import os
import re
import sys
import tempfile

MAX_FILES_PER_FOLDER = 15
SOURCE = re.compile(r"\.(h|hpp|cpp|cu|cuh)$")
INCLUDE = re.compile(r'^\s*#\s*include\s*([<"])([^>"]+)[>"]', re.M)

# What each part of src/ may include (besides itself).
ALLOWED = {
    "chrono_like/base": set(),
    "chrono_like/collision": {"chrono_like/base"},
    "chrono_like/solver": {"chrono_like/base", "chrono_like/collision"},
    "chrono_like": {"chrono_like/base", "chrono_like/collision", "chrono_like/solver"},
    "chrono_like/bullet": {"chrono_like/base", "chrono_like/collision", "chrono_like/solver", "chrono_like"},
    "chrono_like/io": {"chrono_like/base", "chrono_like/collision", "chrono_like/solver", "chrono_like",
                       "chrono_like/bullet"},
    "chrono_like/mpi": {"chrono_like/base", "chrono_like/collision", "chrono_like/solver", "chrono_like"},
    "gpu": {"chrono_like/*"},
    "ces": {"chrono_like/*", "gpu"},
    "dvisim": {"chrono_like/*", "gpu", "ces"},  # the public headers, on top of everything (docs/INSTALL.md)
}
# Deprecated include paths kept for one release (docs/INSTALL.md): each forwards to a public header of src/dvisim/.
FORWARDERS = {"chrono_like/bullet_world.h"}


def part_of(rel):
    """The part (key of ALLOWED) that the file src/<rel> belongs to, or None."""
    folder = os.path.dirname(rel)
    while folder:
        if folder in ALLOWED:
            return folder
        folder = os.path.dirname(folder)
    return None


def may_include(src_part, dst_part):
    if src_part == dst_part:
        return True
    for allowed in ALLOWED[src_part]:
        if allowed.endswith("/*"):  # the folder and everything under it
            if dst_part == allowed[:-2] or dst_part.startswith(allowed[:-1]):
                return True
        elif dst_part == allowed:
            return True
    return False


def problems_in(src):
    """One line per violation in the tree src/."""
    problems = []
    for dirpath, dirnames, filenames in os.walk(src):
        dirnames.sort()
        rel_dir = os.path.relpath(dirpath, src)
        if len(filenames) > MAX_FILES_PER_FOLDER:
            problems.append("src/%s/ holds %d files (at most %d: give it sub-folders)"
                            % (rel_dir, len(filenames), MAX_FILES_PER_FOLDER))
        for name in sorted(filenames):
            if not SOURCE.search(name):
                continue
            path = os.path.join(dirpath, name)
            rel = os.path.relpath(path, src)
            part = part_of(rel)
            if part is None:
                problems.append("src/%s: in no layer (move it into one of the folders the layering names)" % rel)
                continue
            with open(path, encoding="utf-8") as f:
                text = f.read()
            for quote, target in INCLUDE.findall(text):
                # Resolved as the compiler does: "..." next to the file first, then from src/ (the include root).
                found = None
                for base in ((dirpath, src) if quote == '"' else (src,)):
                    candidate = os.path.normpath(os.path.join(base, target))
                    if os.path.isfile(candidate):
                        found = candidate
                        break
                if found is None:
                    continue  # a header of a dependency or of the system
                target_rel = os.path.relpath(found, src)
                if target_rel.startswith(".."):
                    problems.append('src/%s includes "%s", outside src/' % (rel, target))
                    continue
                target_part = part_of(target_rel)
                if rel in FORWARDERS and target_part == "dvisim":
                    continue
                if target_part is None or not may_include(part, target_part):
                    problems.append('src/%s includes "%s": %s/ may not include %s/'
                                    % (rel, target, part, target_part or os.path.dirname(target_rel)))
    return problems


def self_test():
    """Builds a tree with one violation of each kind (and allowed includes beside them) and checks that exactly
    the violating files are reported."""
    files = {
        "src/chrono_like/base/a.h": '#include "chrono_like/collision/b.h"\n',  # up: base -> collision
        "src/chrono_like/base/ok.h": '#include <vector>\n#include "a.h"\n',
        "src/chrono_like/collision/b.h": '#include "chrono_like/base/ok.h"\n',
        "src/chrono_like/solver/c.h": '#include "chrono_like/collision/b.h"\n#include "gpu/g.h"\n',  # core -> gpu
        "src/chrono_like/system.h": '#include "chrono_like/solver/c.h"\n#include <chrono_like/bullet/w.h>\n',  # up
        "src/chrono_like/io/s.h": '#include "chrono_like/system.h"\n#include "chrono_like/bullet/w.h"\n',
        "src/chrono_like/bullet/w.h": '#include "chrono_like/system.h"\n#include "chrono_like/io/s.h"\n',  # up
        "src/chrono_like/x.cpp": '#include "../../apps/p.h"\n',  # outside src/
        "src/gpu/g.h": '#include "chrono_like/io/s.h"\n#include "ces/e.h"\n',  # gpu -> ces
        "src/ces/e.h": '#include "gpu/g.h"\n#include "chrono_like/base/a.h"\n',
        "src/stray.h": "",  # in no layer
        "apps/p.h": "",
    }
    files.update({"src/ces/many/n%02d.txt" % i: "" for i in range(MAX_FILES_PER_FOLDER + 1)})  # a full folder
    expected = {"src/chrono_like/base/a.h", "src/chrono_like/solver/c.h", "src/chrono_like/system.h",
                "src/chrono_like/bullet/w.h", "src/chrono_like/x.cpp", "src/gpu/g.h", "src/stray.h", "src/ces/many/"}
    with tempfile.TemporaryDirectory() as root:
        for rel, text in files.items():
            os.makedirs(os.path.dirname(os.path.join(root, rel)), exist_ok=True)
            with open(os.path.join(root, rel), "w", encoding="utf-8") as f:
                f.write(text)
        found = problems_in(os.path.join(root, "src"))
    flagged = {p.split(" ")[0].rstrip(":") for p in found}
    for p in found:
        print("found: " + p)
    if flagged != expected or len(found) != len(expected):
        print("self-test failed: expected exactly one problem in each of %s, got %s"
              % (sorted(expected), sorted(flagged)))
        return 1
    print("self-test: all %d planted violations found, nothing else" % len(expected))
    return 0


def main():
    if len(sys.argv) > 1 and sys.argv[1] == "--self-test":
        return self_test()
    src = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else
                          os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "src"))
    if not os.path.isdir(os.path.join(src, "chrono_like")):
        print("%s is not dvisim's src/ (no chrono_like/ in it)" % src)
        return 1
    problems = problems_in(src)
    for p in problems:
        print(p)
    if problems:
        print("%d layout problem(s); the layering is in docs/ARCHITECTURE.md, \"Source layout\"" % len(problems))
        return 1
    print("source layout: every include goes downward, no folder holds more than %d files" % MAX_FILES_PER_FOLDER)
    return 0


if __name__ == "__main__":
    sys.exit(main())
