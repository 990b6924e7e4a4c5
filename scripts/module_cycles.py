#!/usr/bin/env python3
"""No import cycle between the modules of any Rust crate: the Rust side of the check that
import-linter's ``acyclic_siblings`` contract makes of the Python package (clients/pyproject.toml).

    python3 scripts/module_cycles.py sim-core scenarios protocol sim-server

``cargo modules dependencies`` (cargo-modules, which reads the crate with rust-analyzer) gives
every item of a crate's library and what it uses. Its own ``--acyclic`` flag fails on any
cycle of *items* (a type and its methods use each other), so the graph is collapsed here to
modules: within each module, an edge between two child modules when an item in one uses an
item in the other, and no child module may be reached back from one it reaches. Exits 1 with
each cycle and an example use per edge; 0 when every crate is acyclic.
"""

from __future__ import annotations

import re
import subprocess
import sys
from collections import defaultdict

NODE = re.compile(r'^\s*"([^"]+)" \[label="([^|"]*)\|')
EDGE = re.compile(r'^\s*"([^"]+)" -> "([^"]+)" \[label="uses"')


def graph(crate: str) -> tuple[set[str], list[tuple[str, str]]]:
    """The crate's modules and its item-to-item uses, from ``cargo modules dependencies``."""
    out = subprocess.run(
        ["cargo", "modules", "dependencies", "-p", crate, "--lib"]
        + ["--no-externs", "--no-sysroot", "--no-owns"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    modules, uses = set(), []
    for line in out.splitlines():
        if m := EDGE.match(line):
            uses.append((m[1], m[2]))
        elif m := NODE.match(line):
            kind = m[2].split()[-1]
            if kind in ("mod", "crate"):
                modules.add(m[1])
    return modules, uses


def module_of(path: str, modules: set[str]) -> str:
    """The innermost module that holds item ``path`` (or is it)."""
    while path not in modules:
        path = path.rsplit("::", 1)[0]
    return path


def sibling_edges(modules: set[str], uses: list[tuple[str, str]]) -> dict:
    """``{parent: {(child_a, child_b): example use}}``: child module ``a`` of ``parent`` uses
    something in its sibling ``b``."""
    out: dict[str, dict[tuple[str, str], tuple[str, str]]] = defaultdict(dict)
    for src, dst in uses:
        a, b = module_of(src, modules).split("::"), module_of(dst, modules).split("::")
        common = 0
        while common < min(len(a), len(b)) and a[common] == b[common]:
            common += 1
        if common < len(a) and common < len(b):  # neither is the other's ancestor
            parent = "::".join(a[:common])
            key = ("::".join(a[: common + 1]), "::".join(b[: common + 1]))
            out[parent].setdefault(key, (src, dst))
    return out


def cycles(edges: dict[tuple[str, str], tuple[str, str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    succ: dict[str, list[str]] = defaultdict(list)
    for a, b in edges:
        succ[a].append(b)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in succ[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted({m for e in edges for m in e}):
        if v not in index:
            visit(v)
    return found


def main(crates: list[str]) -> int:
    broken = 0
    for crate in crates:
        modules, uses = graph(crate)
        bad = []
        for parent, edges in sorted(sibling_edges(modules, uses).items()):
            for comp in cycles(edges):
                inside = {
                    (a, b): e for (a, b), e in edges.items() if a in comp and b in comp
                }
                bad.append((parent, comp, inside))
        if not bad:
            print(f"{crate}: {len(modules)} modules, no cycle")
            continue
        broken += 1
        for parent, comp, inside in bad:
            print(f"{crate}: cycle among the modules of {parent}: {', '.join(comp)}")
            for (a, b), (src, dst) in sorted(inside.items()):
                print(f"    {a} -> {b}  (e.g. {src} uses {dst})")
    return 1 if broken else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:] or ["sim-core", "scenarios", "protocol", "sim-server"]))
