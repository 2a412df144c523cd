#!/usr/bin/env python3
"""The project's size rules, checked in CI: no source file over 800 lines, no function over 100 lines
in the core library (runtime/, kernels/, host/) and none over 150 in the rest of it (base/, python/);
tests and benches are exempt from the function rule.

A function is a brace block that opens at namespace or class scope after a parenthesised header
(comments, strings and preprocessor lines are stripped first). Usage:
    tools/checks/check_code_size.py [ROOT] [--max-file 800] [--max-core-function 100] [--max-function 150]
Prints every violation and exits 1 if there is any.
"""
import argparse
import pathlib
import re
import sys

LIBRARY_DIRS = ("base", "runtime", "kernels", "host", "python")
CORE_DIRS = ("runtime", "kernels", "host")  # held to --max-core-function
ALL_DIRS = LIBRARY_DIRS + ("tests", "bench", "fuzz", "tools", "shaders")
SUFFIXES = {".cpp", ".hpp", ".h", ".c", ".comp", ".glsl", ".py"}


def strip_code(text):
    """Comments, string and char literals and preprocessor lines blanked, newlines kept."""
    out, i, n = [], 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            i = n if j < 0 else j
        elif text.startswith("/*", i):
            j = text.find("*/", i + 2)
            j = n if j < 0 else j + 2
            out.append("\n" * text.count("\n", i, j))
            i = j
        elif c in "\"'":
            m = re.match(r'R"([^(]*)\(', text[i:]) if c == '"' and i > 0 and text[i - 1] == "R" else None
            if m:
                end = text.find(")" + m.group(1) + '"', i)
                j = n if end < 0 else end + len(m.group(1)) + 2
            else:
                j = i + 1
                while j < n and text[j] != c:
                    j += 2 if text[j] == "\\" else 1
                j += 1
            out.append(" " + "\n" * text.count("\n", i, j))
            i = j
        else:
            out.append(c)
            i += 1
    lines = "".join(out).split("\n")
    return "\n".join("" if l.lstrip().startswith("#") else l for l in lines)


SCOPE = re.compile(r"\b(namespace|class|struct|union|enum)\b[^()]*$|extern\s*$")
CONTROL = re.compile(r"\b(if|for|while|switch|catch|do|else|try)\b\s*(\(|$)")


def long_functions(text, limit):
    code = strip_code(text)
    stack = []  # per open brace: ("scope" | "function" | "block", start line)
    header_start, line = 0, 1
    found = []
    for pos, c in enumerate(code):
        if c == "\n":
            line += 1
        elif c in ";}":
            if c == "}" and stack:
                kind, start = stack.pop()
                if kind == "function" and line - start + 1 > limit:
                    found.append((start, line - start + 1))
            header_start = pos + 1
        elif c == "{":
            header = code[header_start:pos].strip()
            at_scope = all(k == "scope" for k, _ in stack)
            if SCOPE.search(header) and "(" not in header.split("{")[-1]:
                kind = "scope"
            elif at_scope and ")" in header and not CONTROL.search(header.split(")")[0]) and "=" not in header.split("(")[0]:
                kind = "function"
            else:
                kind = "block"
            stack.append((kind, line))
            header_start = pos + 1
    return found


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("root", nargs="?", default=pathlib.Path(__file__).resolve().parents[2])
    ap.add_argument("--max-file", type=int, default=800)
    ap.add_argument("--max-core-function", type=int, default=100, help="function lines in " + ", ".join(CORE_DIRS))
    ap.add_argument("--max-function", type=int, default=150, help="function lines in the other library folders")
    a = ap.parse_args()
    root = pathlib.Path(a.root)
    problems = []
    for d in ALL_DIRS:
        for p in sorted((root / d).rglob("*")):
            if p.suffix not in SUFFIXES or not p.is_file() or "fuzz_corpus" in p.parts:
                continue
            text = p.read_text(errors="replace")
            rel = p.relative_to(root)
            lines = text.count("\n") + (0 if text.endswith("\n") else 1)
            if lines > a.max_file:
                problems.append(f"{rel}: {lines} lines (at most {a.max_file})")
            if d in LIBRARY_DIRS and p.suffix in {".cpp", ".hpp", ".h", ".c"}:
                limit = a.max_core_function if d in CORE_DIRS else a.max_function
                for start, length in long_functions(text, limit):
                    problems.append(f"{rel}:{start}: a function of {length} lines (at most {limit})")
    for m in problems:
        print(m)
    print(f"check_code_size: {len(problems)} violation(s)" if problems else "check_code_size: every file and function within the limits")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
