"""The Gymnasium spaces of one controlled vehicle, shared by every env adapter (PettingZoo,
Gymnasium): its observation graph of ``max_agents`` nodes (protocol/SPEC.md section 7) and its
normalised action.

**Bounds.** Every feature's Box is finite (Gymnasium's ``check_env`` wants them so, and tools
that scale by the bounds need them). Where a feature is bounded by its definition the bound is
exact (``heading_diff`` in [-pi, pi], ``is_vehicle`` in [0, 1], speeds and distances >= 0);
where it is bounded only by the world (positions within the perception radius, speeds, the
goal's distance, the risk graph's weights, whose ``u`` is an unbounded KL divergence) the bound
holds with a wide margin in every shipped world (perception radius 15 m, speeds below 10 m/s,
scenes under 200 m across, ``A`` below 60 in the HBS pools) and the adapters clip to it
(:func:`clip_observation`): a world beyond it (a perception radius over 90 m, say) saturates.
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces

from .names import NODE_FEATURES, Feature

__all__ = [
    "ADJACENCY_MAX",
    "FEATURE_HIGH",
    "FEATURE_LOW",
    "action_space",
    "clip_observation",
    "observation_space",
]

#: Per feature (protocol/SPEC.md 7): (low, high), in the feature's unit.
_BOUNDS = {
    Feature.REL_X: (-100.0, 100.0),  # m: within the perception radius, plus footprints
    Feature.REL_Y: (-100.0, 100.0),
    Feature.REL_VX: (-100.0, 100.0),  # m/s: a difference of two speeds
    Feature.REL_VY: (-100.0, 100.0),
    Feature.SPEED: (0.0, 50.0),  # m/s
    Feature.HEADING_DIFF: (-np.pi, np.pi),  # rad, wrapped
    Feature.RADIUS: (0.0, 20.0),  # m: a footprint
    Feature.IS_VEHICLE: (0.0, 1.0),
    Feature.GOAL_DX: (-10_000.0, 10_000.0),  # m: the ego's goal, anywhere in its scene
    Feature.GOAL_DY: (-10_000.0, 10_000.0),
    Feature.GOAL_DIST: (0.0, 15_000.0),
}
#: The lowest and highest value of each of the ``NODE_FEATURES`` features, in order.
FEATURE_LOW = np.array([_BOUNDS[Feature(i)][0] for i in range(NODE_FEATURES)], np.float32)
FEATURE_HIGH = np.array([_BOUNDS[Feature(i)][1] for i in range(NODE_FEATURES)], np.float32)
#: The highest risk-graph weight ``A = psi (1 + lambda u)`` an observation carries.
ADJACENCY_MAX = 1_000.0


def observation_space(max_agents: int) -> spaces.Dict:
    """``features`` ``[M, F]``, ``adjacency`` ``[M, M]`` (the risk graph) and ``mask`` ``[M]``."""
    m = int(max_agents)
    return spaces.Dict(
        {
            "features": spaces.Box(
                np.tile(FEATURE_LOW, (m, 1)), np.tile(FEATURE_HIGH, (m, 1)), dtype=np.float32
            ),
            "adjacency": spaces.Box(0.0, ADJACENCY_MAX, (m, m), np.float32),
            "mask": spaces.MultiBinary(m),
        }
    )


def clip_observation(features: np.ndarray, adjacency: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``features [..., M, F]`` and ``adjacency [..., M, M]`` clipped into
    :func:`observation_space`'s bounds (float32; in place where they are float32 already)."""
    features = np.asarray(features, np.float32)
    adjacency = np.asarray(adjacency, np.float32)
    np.clip(features, FEATURE_LOW, FEATURE_HIGH, out=features)
    np.clip(adjacency, 0.0, ADJACENCY_MAX, out=adjacency)
    return features, adjacency


def action_space() -> spaces.Box:
    """``[acc, omega]`` normalised to ``[-1, 1]`` (the server scales them, SPEC.md 6.2)."""
    return spaces.Box(-1.0, 1.0, (2,), np.float32)
