"""Two drivers' stress scorings side by side: which is harder to break.

For every pedestrian both scorings played (the CR-SFM baseline and each adversary, matched by
checkpoint or script, not by label): the paired difference ``A - B`` in success, episode by
episode (a row's seeds averaged per episode), in at-fault collisions with that pedestrian,
and the difference in their success drops,
``drop_A - drop_B``. A drop is per episode (success against CR-SFM less success against the
adversary), so the second is paired too. Intervals resample the scenes (docs/RESULTS.md,
"Adversarial stress test").
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from sharedspace.adversary.stress import per_episode
from sharedspace.stats import paired_clustered

__all__ = ["compare_drivers", "compare_markdown"]


def compare_drivers(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    """``A - B`` for every pedestrian both stress scorings (:func:`~sharedspace.adversary.
    stress.stress_row`) of one task played, matched by what it is (CR-SFM, a checkpoint, a
    scripted adversary), whatever each scoring labelled it: ``success`` and ``at_fault`` (an
    at-fault collision with that pedestrian; paired per episode) and, for each adversary,
    ``drop`` (``drop_A - drop_B``, paired per episode)."""
    if a["task"] != b["task"] or a["fingerprint"] != b["fingerprint"]:
        raise ValueError(
            f"the scorings are of different tasks: {a['task']} ({a['fingerprint']}) and "
            f"{b['task']} ({b['fingerprint']})"
        )
    in_a, in_b = ({cond["adversary"]: cond for cond in r["conditions"].values()} for r in (a, b))
    if None not in in_a or None not in in_b:
        raise ValueError("each scoring needs its CR-SFM baseline (an adversary of None)")
    base_a, base_b = (per_episode(x[None]["episodes"], "success") for x in (in_a, in_b))
    out: dict[str, Any] = {"a": a["driver"], "b": b["driver"], "task": a["task"], "by": {}}
    for label, cond_a in a["conditions"].items():
        cond_b = in_b.get(cond_a["adversary"])
        if cond_b is None:
            continue
        sa, sb = (per_episode(c["episodes"], "success") for c in (cond_a, cond_b))
        fa, fb = (per_episode(c["episodes"], "fault") for c in (cond_a, cond_b))
        entry: dict[str, Any] = {"adversary": cond_a["adversary"]}
        entry["success"], entry["at_fault"] = paired_clustered(sa, sb), paired_clustered(fa, fb)
        if cond_a["adversary"] is not None:
            drop_a = {k: base_a[k] - v for k, v in sa.items() if k in base_a}
            drop_b = {k: base_b[k] - v for k, v in sb.items() if k in base_b}
            entry["drop"] = paired_clustered(drop_a, drop_b)
        out["by"][label] = entry
    return out


def compare_markdown(result: dict[str, Any]) -> str:
    """The comparison as a table: one row per pedestrian."""
    lines = [
        f"`{result['a']}` − `{result['b']}` on `{result['task']}`, paired per episode "
        "(scenes resampled, 95 %):",
        "",
        "| pedestrian (A's label) | adversary | success A − B | at fault A − B "
        "| success drop A − B |",
        "|---|---|---|---|---|",
    ]
    for label, entry in result["by"].items():
        cells = [
            f"{d['diff']:+.3f} [{d['lo']:+.3f}, {d['hi']:+.3f}]" if d else "—"
            for d in (entry["success"], entry["at_fault"], entry.get("drop"))
        ]
        what = entry["adversary"] or "CR-SFM"
        lines.append(f"| {label} | `{Path(what).name}` | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
