"""Names the protocol defines once: the observation's node features and the reward terms.

``names.json`` next to this file is written from the protocol crate (``FEATURE_NAMES``, sim-core's
``REWARD_TERM_NAMES``), and a Rust test (``protocol/tests/golden.rs``) fails when the two differ
(regenerate with ``UPDATE_GOLDEN=1 cargo test -p protocol``). Index features by name with
:class:`Feature` (``features[..., Feature.SPEED]``) rather than by number.
"""

from __future__ import annotations

import enum
import json
from importlib import resources

_DOC = json.loads(resources.files(__package__).joinpath("names.json").read_text())

__all__ = [
    "AGENT_GROUPS",
    "FEATURE_NAMES",
    "FEATURE_SCALE",
    "NODE_FEATURES",
    "REWARD_TERMS",
    "Feature",
    "agent_group",
]

#: Node features of an observation, in order (protocol/SPEC.md section 7).
FEATURE_NAMES: tuple[str, ...] = tuple(_DOC["feature_names"])
#: Features per node, ``F``.
NODE_FEATURES: int = len(FEATURE_NAMES)
#: A fixed scale per node feature (FEATURE_NAMES order): features divided by it are O(1), the
#: networks' inputs (m, m, m/s, m/s, m/s, rad, m, flag, m, m, m).
FEATURE_SCALE: tuple[float, ...] = (10.0, 10.0, 5.0, 5.0, 5.0, 3.14159, 1.0, 1.0, 20.0, 20.0, 20.0)
#: The reward terms, in order (``reward`` is their sum; SPEC section 8.2).
REWARD_TERMS: tuple[str, ...] = tuple(_DOC["reward_terms"])

#: Each feature's column: ``Feature.SPEED == 4``, ``Feature.GOAL_DIST == 10``.
Feature = enum.IntEnum("Feature", [(name.upper(), i) for i, name in enumerate(FEATURE_NAMES)])

#: The kinds of agent a client may drive, by the prefix of the agent's name (SPEC 5.2):
#: ``vehicle_{k}`` (``vehicle_0``: the scenario's ego) and ``pedestrian_{k}``.
AGENT_GROUPS = ("vehicle", "pedestrian")


def agent_group(agent: str) -> str:
    """The kind of an external agent's name, ``vehicle`` or ``pedestrian``; a ``ValueError``
    naming it otherwise."""
    kind, _, k = agent.rpartition("_")
    if kind in AGENT_GROUPS and k.isdigit() and (k == "0" or not k.startswith("0")):
        return kind
    raise ValueError(f"external agent {agent!r}: expected vehicle_{{k}} or pedestrian_{{k}}")
