"""The pedestrian and vehicle models, from the lists in sim-core (``sim_core::params::MODELS``,
``VEHICLE_MODELS``).

``models.json`` next to this file is written from that table and a Rust test
(``sim-core/tests/models.rs``) fails when the two differ, so every Python list of models (the
clients' defaults, calibration, tables and figures) derives from here rather than restating it.
"""

from __future__ import annotations

import json
from importlib import resources

_DOC = json.loads(resources.files(__package__).joinpath("models.json").read_text())

#: Every model, in sim-core's order: ``{"name", "label", "social_force", "risk", "cognitive"}``.
MODELS: tuple[dict, ...] = tuple(_DOC["models"])
#: Every model's name (``cv``, ``sfm``, ...), as on the wire and in configs.
PEDESTRIAN_MODELS: tuple[str, ...] = tuple(m["name"] for m in MODELS)
#: The models with social forces (and so parameters to calibrate).
SOCIAL_FORCE_MODELS: tuple[str, ...] = tuple(m["name"] for m in MODELS if m["social_force"])
#: The models a pedestrian evaluation compares (all but ``replay``, which repeats the record).
EVALUATED_MODELS: tuple[str, ...] = tuple(n for n in PEDESTRIAN_MODELS if n != "replay")
#: Table and figure label of each model (the paper's).
LABELS: dict[str, str] = {m["name"]: m["label"] for m in MODELS}
#: The default model (the paper's).
DEFAULT_MODEL: str = _DOC["default"]

#: Every vehicle model of the cars nobody controls: ``{"name", "label", "reactive"}``.
VEHICLE_MODEL_TABLE: tuple[dict, ...] = tuple(_DOC["vehicle_models"])
#: Every vehicle model's name (``replay``, ``idm``), as on the wire and in configs.
VEHICLE_MODELS: tuple[str, ...] = tuple(m["name"] for m in VEHICLE_MODEL_TABLE)
#: The default vehicle model (``replay``: the paper's set-up).
DEFAULT_VEHICLE_MODEL: str = _DOC["vehicle_default"]
