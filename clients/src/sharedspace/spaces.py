"""The Gymnasium spaces of one controlled vehicle, shared by every env adapter (PettingZoo,
Gymnasium): its observation graph of ``max_agents`` nodes (protocol/SPEC.md section 7) and its
normalised action."""

from __future__ import annotations

import numpy as np
from gymnasium import spaces

from .names import NODE_FEATURES

__all__ = ["observation_space", "action_space"]


def observation_space(max_agents: int) -> spaces.Dict:
    """``features`` ``[M, F]``, ``adjacency`` ``[M, M]`` (the risk graph) and ``mask`` ``[M]``."""
    m = int(max_agents)
    return spaces.Dict(
        {
            "features": spaces.Box(-np.inf, np.inf, (m, NODE_FEATURES), np.float32),
            "adjacency": spaces.Box(0.0, np.inf, (m, m), np.float32),
            "mask": spaces.MultiBinary(m),
        }
    )


def action_space() -> spaces.Box:
    """``[acc, omega]`` normalised to ``[-1, 1]`` (the server scales them, SPEC.md 6.2)."""
    return spaces.Box(-1.0, 1.0, (2,), np.float32)
