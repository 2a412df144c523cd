#!/usr/bin/env python3
"""The project's size rules, checked in CI over the whole tree: no source file over 800 lines, and no
function over 100 lines, in C++ (library, Python bindings, tests, benches, fuzzers) and in Python
(tools, the package, tests, the workflow's scripts) alike.

A C++ function is a brace block that opens at namespace or class scope after a parenthesised header
(comments, strings and preprocessor lines are stripped first); a Python function is a def (methods
and nested defs each on their own: a nested def's lines also count in its parent's). Usage:
    tools/checks/check_code_size.py [ROOT] [--max-file 800] [--max-function 100]
Prints every violation and exits 1 if there is any.
"""
import argparse
import ast
import pathlib
import re
import sys

SOURCE_DIRS = ("base", "runtime", "kernels", "host", "python", "tests", "bench", "fuzz", "tools", "shaders", "workflow", "scripts",
               "examples")
CPP_SUFFIXES = {".cpp", ".hpp", ".h", ".c"}
SUFFIXES = CPP_SUFFIXES | {".comp", ".glsl", ".py"}
# Functions held to a larger limit, each with the reason and who removes it (none now; the last two,
# bench_kernels.cpp main and bench_model.cpp run_bench, were split by issue 49's gpu-tuner branch).
TEMPORARY_EXEMPTIONS = {}


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
    """(start line, length, name) of every C++ function over `limit` lines."""
    code = strip_code(text)
    stack = []  # per open brace: ("scope" | "function" | "block", start line)
    header_start, line = 0, 1
    found = []
    for pos, c in enumerate(code):
        if c == "\n":
            line += 1
        elif c in ";}":
            if c == "}" and stack:
                kind, start, name = stack.pop()
                if kind == "function" and line - start + 1 > limit:
                    found.append((start, line - start + 1, name))
            header_start = pos + 1
        elif c == "{":
            header = code[header_start:pos].strip()
            at_scope = all(k == "scope" for k, _, _ in stack)
            if SCOPE.search(header) and "(" not in header.split("{")[-1]:
                kind = "scope"
            elif at_scope and ")" in header and not CONTROL.search(header.split(")")[0]) and "=" not in header.split("(")[0]:
                kind = "function"
            else:
                kind = "block"
            names = re.findall(r"([A-Za-z_~][\w:~]*)\s*\(", header)
            stack.append((kind, line, names[0].split("::")[-1] if names else "?"))
            header_start = pos + 1
    return found


def long_python_functions(text, limit):
    """(start line, length, name) of every Python def over `limit` lines (decorators included)."""
    found = []
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            start = min([node.lineno] + [d.lineno for d in node.decorator_list])
            length = node.end_lineno - start + 1
            if length > limit:
                found.append((start, length, node.name))
    return found


def sources(root):
    """Every source file of the tree (the fuzz corpus and build folders left out), in order."""
    for d in SOURCE_DIRS:
        for p in sorted((root / d).rglob("*")):
            if p.suffix in SUFFIXES and p.is_file() and "fuzz_corpus" not in p.parts and "__pycache__" not in p.parts:
                yield p
    yield from (p for p in sorted(root.glob("*.py")) if p.is_file())


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("root", nargs="?", default=pathlib.Path(__file__).resolve().parents[2])
    ap.add_argument("--max-file", type=int, default=800)
    ap.add_argument("--max-function", type=int, default=100)
    a = ap.parse_args()
    root = pathlib.Path(a.root)
    problems = []
    for p in sources(root):
        text = p.read_text(errors="replace")
        rel = p.relative_to(root).as_posix()
        lines = text.count("\n") + (0 if text.endswith("\n") else 1)
        if lines > a.max_file:
            problems.append(f"{rel}: {lines} lines (at most {a.max_file})")
        if p.suffix in CPP_SUFFIXES:
            found = long_functions(text, a.max_function)
        elif p.suffix == ".py":
            try:
                found = long_python_functions(text, a.max_function)
            except SyntaxError as e:
                problems.append(f"{rel}:{e.lineno}: not Python the checker can read ({e.msg})")
                continue
        else:
            found = []
        for start, length, name in found:
            allowed = TEMPORARY_EXEMPTIONS.get((rel, name), a.max_function)
            if length > allowed:
                problems.append(f"{rel}:{start}: {name}, a function of {length} lines (at most {a.max_function})")
    for m in problems:
        print(m)
    print(f"check_code_size: {len(problems)} violation(s)" if problems else "check_code_size: every file and function within the limits")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
