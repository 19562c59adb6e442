#!/usr/bin/env python3
"""Lists the functions in src/ longer than a limit (CONTRIBUTING.md, "Short functions") and exits 1 when there is any.

    python3 tests/check_function_length.py [--max N] [DIR ...]   (default 100 lines, the src/ beside tests/)
    python3 tests/check_function_length.py --self-test           (it measures made-up sources right)

A function is a brace block whose header has a parameter list and which sits directly in a namespace, a class or
a struct (or at file scope); a lambda or a local block counts toward the function around it. Its length runs from
the line of its name to the line of its closing brace. Comments, string and character literals and preprocessor
lines are blanked before the braces are read, so braces inside them do not count.
"""
import os
import re
import sys
import tempfile

ATTRIBUTES = {"__launch_bounds__", "__attribute__", "alignas", "__declspec"}
SOURCE = re.compile(r"\.(h|hpp|cpp|cu|cuh)$")
CONTROL = re.compile(r"^(if|for|while|switch|catch|do|else|try)\b")
SCOPE = re.compile(r"^(namespace|class|struct|union|enum|extern)\b|\b(class|struct|union|namespace)\s+[\w:]*\s*(final\s*)?(:[^()]*)?$")


def blank(text):
    """The text with comments, literals and preprocessor lines replaced by spaces (newlines kept)."""
    out, i, n = [], 0, len(text)
    line_start = True
    while i < n:
        c = text[i]
        if line_start and c == "#" or (line_start and c in " \t" and text[i:].lstrip(" \t").startswith("#")):
            j = i
            while j < n:  # a directive, with its continuation lines
                k = text.find("\n", j)
                if k < 0:
                    k = n
                if k > 0 and text[k - 1] == "\\":
                    j = k + 1
                    continue
                break
            out.append(re.sub(r"[^\n]", " ", text[i:k]))
            i = k
            continue
        if text.startswith("//", i):
            k = text.find("\n", i)
            k = n if k < 0 else k
            out.append(" " * (k - i))
            i = k
            continue
        if text.startswith("/*", i):
            k = text.find("*/", i + 2)
            k = n if k < 0 else k + 2
            out.append(re.sub(r"[^\n]", " ", text[i:k]))
            i = k
            continue
        m = re.match(r'R"([^(\s]*)\(', text[i:i + 20])
        if m:  # raw string literal
            end = text.find(")" + m.group(1) + '"', i)
            k = n if end < 0 else end + len(m.group(1)) + 2
            out.append(re.sub(r"[^\n]", " ", text[i:k]))
            i = k
            continue
        if c in "\"'" and not (c == "'" and i > 0 and text[i - 1].isalnum()):  # 1'000 digit separators
            j = i + 1
            while j < n and text[j] != c and text[j] != "\n":
                j += 2 if text[j] == "\\" else 1
            out.append(c + " " * (min(j, n) - i - 1) + (c if j < n else ""))
            i = j + 1
            continue
        out.append(c)
        line_start = c == "\n" or (line_start and c in " \t")
        i += 1
    return "".join(out)


def functions(text):
    """(name, first line, last line) of each function (see the module's doc)."""
    code = blank(text)
    result = []
    stack = []  # per open brace: ("scope" | "function" | "block", name, first line)
    header_start = 0
    line = 1
    for i, c in enumerate(code):
        if c == "\n":
            line += 1
        elif c == "{":
            header = " ".join(code[header_start:i].split())
            in_function = any(kind != "scope" for kind, _, _ in stack)
            if in_function:
                stack.append(("block", "", line))
            elif SCOPE.search(header) and "(" not in header.split("{")[0]:
                stack.append(("scope", "", line))
            elif "(" in header and not CONTROL.match(header) and not header.endswith("=") and ")" in header:
                name = [w for w in re.findall(r"([~\w:<>]+)\s*\(", header) if w not in ATTRIBUTES]
                first = line - code[header_start:i].lstrip().count("\n")
                stack.append(("function", name[0] if name else header[:40], first))
            else:
                stack.append(("scope" if not in_function else "block", "", line))  # initialisers, enums, ...
            header_start = i + 1
        elif c == "}":
            if stack:
                kind, name, first = stack.pop()
                if kind == "function":
                    result.append((name, first, line))
            header_start = i + 1
        elif c == ";":
            header_start = i + 1
    return result


# Code of other projects kept unchanged as benchmark input (Bullet's example programs of bench/dropin_corpus/): not
# ours to split.
FOREIGN = os.path.join("dropin_corpus", "third_party", "bullet3_examples")


def long_functions(src_dir, max_lines):
    found = []
    for root, _, files in os.walk(src_dir):
        if FOREIGN in root:
            continue
        for f in sorted(files):
            if not SOURCE.search(f):
                continue
            path = os.path.join(root, f)
            with open(path, encoding="utf-8", errors="replace") as fh:
                text = fh.read()
            for name, first, last in functions(text):
                if last - first + 1 > max_lines:
                    found.append((os.path.relpath(path, os.path.dirname(src_dir)), first, name, last - first + 1))
    return sorted(found)


def self_test():
    short = "namespace a {\nint f(int x) {\n  if (x) {\n    return 1;\n  }\n  return 0;\n}\n}  // namespace a\n"
    body = "\n".join("  x += %d;  // }" % i for i in range(120))
    long_fn = ("struct S {\n  void g(int& x) const {\n" + body + "\n    auto l = [&](int y) { return y; };\n"
               "    const char* s = \"{\";\n  }\n};\n#define M(x) { x }\n")
    with tempfile.TemporaryDirectory() as root:
        src = os.path.join(root, "src")
        os.makedirs(src)
        for name, text in (("a.cpp", short), ("b.h", long_fn)):
            with open(os.path.join(src, name), "w", encoding="utf-8") as fh:
                fh.write(text)
        found = long_functions(src, 100)
    if len(found) != 1 or found[0][0] != os.path.join("src", "b.h") or found[0][2] != "g" or found[0][3] != 124:
        print("self-test failed: expected exactly src/b.h g (124 lines), got %s" % found)
        return 1
    print("self-test: the 124-line function found with its length, the short one not")
    return 0


def main(argv):
    if "--self-test" in argv:
        return self_test()
    max_lines = 100
    if "--max" in argv:
        k = argv.index("--max")
        max_lines = int(argv[k + 1])
        argv = argv[:k] + argv[k + 2:]
    dirs = argv[1:] or [os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "src")]
    found = [f for d in dirs for f in long_functions(os.path.abspath(d), max_lines)]
    for path, first, name, n in found:
        print("%s:%d: %s is %d lines (at most %d)" % (path, first, name, n, max_lines))
    if found:
        return 1
    names = ", ".join(os.path.basename(os.path.abspath(d)) + "/" for d in dirs)
    print("function length: every function in %s is at most %d lines" % (names, max_lines))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
