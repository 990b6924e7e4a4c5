#!/usr/bin/env python3
"""Functions longer than a limit (default 80 lines) outside tests: Python by its syntax tree,
Rust by brace matching (strings, chars and comments stripped; `#[cfg(test)]` modules skipped).

    python3 scripts/long_functions.py [--limit 80] clients/src sim-server/src

Prints `lines path name` per function over the limit, longest first; exits 1 if any is listed
beyond those named with --allow (the SAC loop: `sac.py:train`).
"""

from __future__ import annotations

import argparse
import ast
import re
import sys
from pathlib import Path

RUST_FN = re.compile(
    r"^\s*(pub(\([^)]*\))?\s+)?(async\s+)?(const\s+)?(unsafe\s+)?fn\s+(\w+)"
)


def python_functions(path: Path):
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            yield node.name, node.end_lineno - node.lineno + 1


def rust_functions(path: Path):
    lines = path.read_text().splitlines()
    i = 0
    while i < len(lines):
        if lines[i].strip().startswith("#[cfg(test)]"):
            return
        m = RUST_FN.match(lines[i])
        if not m:
            i += 1
            continue
        depth, started, j = 0, False, i
        while j < len(lines):
            code = re.sub(r'"(\\.|[^"\\])*"', '""', lines[j])
            code = re.sub(r"'(\\.|[^'\\])'", "''", re.sub(r"//.*", "", code))
            depth += code.count("{") - code.count("}")
            started = started or "{" in code
            if (started and depth <= 0) or (
                not started and code.rstrip().endswith(";")
            ):
                break
            j += 1
        yield m[6], j - i + 1
        i = j + 1


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("roots", nargs="+")
    ap.add_argument("--limit", type=int, default=80)
    ap.add_argument(
        "--allow", nargs="*", default=["sac.py:train"], help="FILE:FUNCTION"
    )
    args = ap.parse_args()
    found = []
    for root in args.roots:
        for path in sorted(Path(root).rglob("*")):
            if "tests" in path.parts or path.name == "tests.rs":
                continue
            scan = {".py": python_functions, ".rs": rust_functions}.get(path.suffix)
            for name, length in scan(path) if scan else ():
                if length > args.limit:
                    found.append((length, str(path), name))
    bad = 0
    for length, path, name in sorted(found, reverse=True):
        allowed = f"{Path(path).name}:{name}" in args.allow
        bad += not allowed
        print(f"{length:4d} {path} {name}" + ("  (allowed)" if allowed else ""))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
