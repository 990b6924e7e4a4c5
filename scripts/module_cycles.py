#!/usr/bin/env python3
"""No import cycle between the modules of any Rust crate: the Rust side of the check that
import-linter's ``acyclic_siblings`` contract makes of the Python package (clients/pyproject.toml).

    python3 scripts/module_cycles.py sim-core scenarios protocol sim-server

``rust_uses.py`` (beside this file) reads each crate's library source: its modules, and for
each module the modules that define what it names (``use`` declarations and ``crate::`` /
``super::`` paths, re-exports followed). Within each module, an edge between two child modules
when one uses something in the other, and no child module may be reached back from one it
reaches. Exits 1 with each cycle and an example use per edge; 0 when every crate is acyclic.

It needs nothing but Python: it replaced cargo-modules (rust-analyzer), which took six minutes
to build on every fresh clone. On this workspace it finds every sibling edge cargo-modules 0.27
found, and more (modules behind ``cfg`` attributes, which it reads all of).
"""

from __future__ import annotations

import sys
from collections import defaultdict
from pathlib import Path

from rust_uses import module_uses


def graph(crate: str) -> tuple[set[str], list[tuple[str, str]]]:
    """The crate's modules and its module-to-module uses, read from ``<crate>/src``."""
    return module_uses(Path(crate))


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
