"""A driver's stress scoring (:func:`sharedspace.adversary.stress.stress_row`) as markdown."""

from __future__ import annotations

from typing import Any

__all__ = ["stress_markdown"]


def _cell(rate: dict[str, Any]) -> str:
    lo, hi = rate["ci95"]
    return f"{rate['rate']:.3f} [{lo:.3f}, {hi:.3f}]"


def _diff(d: dict[str, Any] | None) -> str:
    if not d:
        return "—"
    return f"{d['diff']:+.3f} [{d['lo']:+.3f}, {d['hi']:+.3f}]"


def stress_markdown(result: dict[str, Any]) -> str:
    """One row per condition: the driver's success, collision and at-fault collision with the
    scene's adversary pedestrian (CR-SFM's, or the learner) and with anyone (Wilson 95 %), the
    adversary's touches that were not the driver's fault, and the paired drop in success and
    rise in at-fault collisions with it against CR-SFM (scenes resampled)."""
    lines = [
        f"Driver `{result['driver']}` on `{result['task']}` (fingerprint {result['fingerprint']}):",
        "",
        "| pedestrian | episodes | success | collision | at fault (it) | at fault (anyone) "
        "| adversary to blame | success drop | at-fault rise |",
        "|---|---:|---|---|---|---|---|---|---|",
    ]
    for label, cond in result["conditions"].items():
        s = cond["summary"]
        lines.append(
            f"| {label} | {s['episodes']} | {_cell(s['success'])} | {_cell(s['collision'])} | "
            f"{_cell(s['at_fault'])} | {_cell(s['at_fault_any'])} | "
            f"{_cell(s['adversary_blamed'])} | "
            f"{_diff(cond.get('drop'))} | {_diff(cond.get('fault_rise'))} |"
        )
    return "\n".join(lines) + "\n"
