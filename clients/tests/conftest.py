"""Shared fixtures; prints the reference cross-check's error table at the end of a run."""

from __future__ import annotations

import crosscheck


def pytest_terminal_summary(terminalreporter):
    rows = crosscheck.RESULTS
    if not rows:
        return
    tr = terminalreporter
    tr.section("reference vs Rust cross-check: max abs errors")
    tr.write_line(
        f"{'set':<10} {'model':<7} {'runs':>4} {'steps':>6} {'pos m':>9} {'vel':>9} "
        f"{'psi':>9} {'u':>9} {'A':>9} {'reward':>9}"
    )
    groups: dict[tuple[str, str], list] = {}
    for r in rows:
        groups.setdefault((r["set"], r["model"]), []).append(r)
    for (name, model), rs in sorted(groups.items()):

        def mx(k, rs=rs):
            return max(r[k] for r in rs)

        tr.write_line(
            f"{name:<10} {model:<7} {len(rs):>4} {sum(r['steps'] for r in rs):>6} "
            f"{mx('pos'):9.1e} {mx('vel'):9.1e} {mx('psi'):9.1e} {mx('u'):9.1e} "
            f"{mx('a'):9.1e} {mx('reward'):9.1e}"
        )
