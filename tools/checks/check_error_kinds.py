#!/usr/bin/env python3
"""Fails on a vkunroll::Error the library throws without a kind (base/error.hpp ErrorKind), outside
the reviewed list tools/checks/bare_errors_allowed.txt.

A plain Error(text) is "unspecified": the CLI and Python treat it as bad input data (exit 65,
ValueError), which is wrong for a broken invariant (internal, 70), a missing file (66) or an I/O
failure (74). Throw the kind's class (DataError, UsageError, InputMissingError, IoError,
InternalError, ...) or Error(text, kind). See docs/errors.md.

Usage: check_error_kinds.py ROOT [--list]   (--list prints every bare construction)
"""
import re
import sys
from pathlib import Path

LIBRARY = ("base", "runtime", "kernels", "host", "python/src")
ALLOW_FILE = Path("tools/checks/bare_errors_allowed.txt")
# The error classes themselves (their constructors call Error(text, kind)).
DEFINITIONS = {"base/error.hpp", "base/error.cpp"}
CONSTRUCTION = re.compile(r"(?<![\w:])(?:vkunroll::)?Error\s*[({]")


def code_only(text):
    """The text with comments, string and character literals blanked (lengths kept)."""
    out, i, n = [], 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            out.append(" " * (j - i))
            i = j
        elif text.startswith("/*", i):
            j = text.find("*/", i + 2)
            j = n if j < 0 else j + 2
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif text.startswith('R"', i):
            m = re.match(r'R"([^(]*)\(', text[i:])
            end = text.find(")" + (m.group(1) if m else "") + '"', i)
            j = n if end < 0 else end + len(m.group(1) if m else "") + 2
            out.append('""' + re.sub(r"[^\n]", " ", text[i + 2:j]))
            i = j
        elif c in "\"'" and not (c == "'" and i and text[i - 1].isalnum()):  # 1'000: a digit separator
            j = i + 1
            while j < n and text[j] != c:
                j += 2 if text[j] == "\\" else 1
            out.append(c + " " * (j - i - 1) + c)
            i = j + 1
        else:
            out.append(c)
            i += 1
    return "".join(out)


def argument_count(code, open_at):
    """Top-level arguments of the call whose bracket is at open_at."""
    close = {"(": ")", "{": "}"}[code[open_at]]
    depth, args, empty = 0, 1, True
    for j in range(open_at, len(code)):
        ch = code[j]
        if ch in "([{<" and not (ch == "<" and code[j + 1:j + 2] in "<="):
            depth += ch != "<"
        elif ch in ")]}":
            depth -= 1
            if depth == 0 and ch == close:
                return 0 if empty else args
        elif ch == "," and depth == 1:
            args += 1
        if depth >= 1 and not ch.isspace() and j != open_at:
            empty = False
    return args


def bare_constructions(path, rel):
    code = code_only(path.read_text(errors="replace"))
    for m in CONSTRUCTION.finditer(code):
        if argument_count(code, m.end() - 1) == 1:
            yield code.count("\n", 0, m.start()) + 1


def allowed(root):
    """{path or folder/: count or None (any)} from the reviewed list."""
    rules = {}
    for line in (root / ALLOW_FILE).read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            where, count = line.split()
            rules[where] = None if count == "*" else int(count)
    return rules


def main():
    root = Path(sys.argv[1] if len(sys.argv) > 1 else ".").resolve()
    rules = allowed(root)
    found = {}
    for top in LIBRARY:
        for path in sorted((root / top).rglob("*")):
            rel = path.relative_to(root).as_posix()
            if path.suffix in (".cpp", ".hpp") and rel not in DEFINITIONS:
                lines = list(bare_constructions(path, rel))
                if lines:
                    found[rel] = lines
    if "--list" in sys.argv:
        for rel, lines in found.items():
            print(f"{rel}: {len(lines)}: lines {', '.join(map(str, lines))}")
    problems, total = [], sum(len(v) for v in found.values())
    for rel, lines in found.items():
        folder = next((w for w in rules if w.endswith("/") and rel.startswith(w)), None)
        limit = rules.get(rel, rules.get(folder, 0) if folder else 0)
        if limit is not None and len(lines) > limit:
            problems.append(f"{rel}: {len(lines)} Error(...) without a kind (allowed {limit}), lines "
                            f"{', '.join(map(str, lines))}: throw a kind (DataError, UsageError, InputMissingError, "
                            "IoError, InternalError, ...; docs/errors.md)")
    for where, limit in rules.items():
        if limit is not None and not where.endswith("/") and len(found.get(where, [])) < limit:
            print(f"note: {where} now has {len(found.get(where, []))} bare errors, the list allows {limit}: lower it")
    print(f"{total} bare Error constructions in the library, {len(problems)} files over the reviewed list")
    for p in problems:
        print(p)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
