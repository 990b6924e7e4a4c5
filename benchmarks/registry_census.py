"""Where the Python package names its algorithms and networks: the census the learner-design
issue asks for, of one source tree (run it on an old checkout too, for before and after).

- **lists**: literals (tuple, list, set, dict keys) holding two or more algorithm names, or two
  or more network names;
- **branches**: comparisons (``==``, ``!=``, ``in``, ``not in``) of anything against a literal
  algorithm or network name, or a literal tuple of them.

Usage: python benchmarks/registry_census.py [clients/src/sharedspace]
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

ALGORITHMS = {"sac", "ppo", "mappo", "ippo", "masac"}
NETWORKS = {"gcn_risk", "gcn_uniform", "mlp", "g_sac_cog", "g_sac_nocog", "s_sac", "gcn_cog"}
NETWORKS |= {"gcn_nocog"}


def _strings(node: ast.AST) -> list[str]:
    elts = node.keys if isinstance(node, ast.Dict) else getattr(node, "elts", [])
    return [e.value for e in elts if isinstance(e, ast.Constant) and isinstance(e.value, str)]


def census(root: Path) -> dict[str, list[str]]:
    found: dict[str, list[str]] = {
        "algorithm lists": [],
        "network lists": [],
        "branches on a name": [],
    }
    for path in sorted(root.rglob("*.py")):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            where = f"{path.relative_to(root)}:{getattr(node, 'lineno', 0)}"
            if isinstance(node, ast.Tuple | ast.List | ast.Set | ast.Dict):
                names = set(_strings(node))
                if len(names & ALGORITHMS) >= 2:
                    found["algorithm lists"].append(where)
                if len(names & NETWORKS) >= 2:
                    found["network lists"].append(where)
            if isinstance(node, ast.Compare):
                for op, right in zip(node.ops, node.comparators, strict=True):
                    if not isinstance(op, ast.Eq | ast.NotEq | ast.In | ast.NotIn):
                        continue
                    values = {right.value} if isinstance(right, ast.Constant) else set()
                    values |= set(_strings(right))
                    if values & (ALGORITHMS | NETWORKS):
                        found["branches on a name"].append(where)
    return found


def main() -> int:
    root = Path(sys.argv[1] if len(sys.argv) > 1 else "clients/src/sharedspace")
    for kind, places in census(root).items():
        print(f"{kind}: {len(places)}  {' '.join(places)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
