#!/usr/bin/env python3
"""Checks the installed header list of src/CMakeLists.txt (docs/INSTALL.md, "Public headers") and exits 1 on a mismatch.

    python3 tests/check_public_headers.py [ROOT]          (default: the checkout above tests/)
    python3 tests/check_public_headers.py --list [ROOT]   (the installed paths under include/dvisim/, one a line)

DVISIM_INTERNAL_HEADERS must be exactly the internal headers that the public headers (DVISIM_PUBLIC_HEADERS, in
src/dvisim/) and the deprecated paths (DVISIM_COMPAT_HEADERS) include, directly or through other internal headers:
one missing breaks an installed consumer's build, one more installs a header no public one needs.
"""
import os
import re
import sys

INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"', re.M)


def cmake_list(text, name):
    m = re.search(r"set\(" + name + r"\s+([^)]*)\)", text)
    if not m:
        raise SystemExit(f"check_public_headers: no set({name} ...) in src/CMakeLists.txt")
    return m.group(1).split()


def closure(src, roots, problems):
    seen, stack = set(), list(roots)
    while stack:
        header = stack.pop()
        if header in seen:
            continue
        seen.add(header)
        with open(os.path.join(src, header)) as f:
            for inc in INCLUDE.findall(f.read()):
                if os.path.exists(os.path.join(src, inc)):
                    stack.append(inc)
                else:
                    problems.append(f"src/{header}: includes \"{inc}\", not a header of src/")
    return seen


def count_headers(src):
    return sum(1 for _, _, files in os.walk(src) for f in files if f.endswith((".h", ".cuh")))


def main():
    args = sys.argv[1:]
    list_only = "--list" in args
    args = [a for a in args if a != "--list"]
    root = args[0] if args else os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    src = os.path.join(root, "src")
    text = open(os.path.join(src, "CMakeLists.txt")).read()
    public = cmake_list(text, "DVISIM_PUBLIC_HEADERS")
    compat = cmake_list(text, "DVISIM_COMPAT_HEADERS")
    listed = cmake_list(text, "DVISIM_INTERNAL_HEADERS")
    if list_only:  # as installed under include/dvisim/
        print("\n".join(sorted([os.path.basename(h) for h in public] + ["internal/" + h for h in compat + listed])))
        return 0
    problems, roots = [], []
    for header in public + compat:
        with open(os.path.join(src, header)) as f:
            for inc in INCLUDE.findall(f.read()):
                if inc in public:
                    continue
                if inc.startswith("dvisim/") or not os.path.exists(os.path.join(src, inc)):
                    problems.append(f"src/{header}: includes \"{inc}\", neither public nor a header of src/")
                else:
                    roots.append(inc)
    needed = closure(src, roots, problems)
    for h in sorted(needed - set(listed)):
        problems.append(f"{h}: included by a public header but not in DVISIM_INTERNAL_HEADERS (not installed)")
    for h in sorted(set(listed) - needed):
        problems.append(f"{h}: in DVISIM_INTERNAL_HEADERS but no public header includes it")
    for p in problems:
        print(p)
    print(f"{len(public)} public headers, {len(compat)} deprecated paths, {len(needed)} internal headers installed "
          f"of {count_headers(src) - len(public) - len(compat)}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
