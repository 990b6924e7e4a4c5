"""Shared pieces: the parameter spaces of the models and a driver for ``sim-server eval-peds``."""

from __future__ import annotations

import json
import math
import subprocess
from dataclasses import dataclass
from pathlib import Path

from sharedspace.models import MODELS

REPO = Path(__file__).resolve().parent.parent
DEFAULT_SERVER = REPO / "target" / "release" / "sim-server"


@dataclass(frozen=True)
class Param:
    """One calibrated parameter: where it lives, its physical bounds, and the search scale."""

    name: str  # e.g. "tau", "gamma1"
    section: str  # "force" (pedestrians.<model>.<name>) or "risk" (models.<model>.risk.<name>)
    low: float
    high: float
    log: bool  # search log10 of the value (scale parameters)

    def bounds(self) -> tuple[float, float]:
        if self.log:
            return (math.log10(self.low), math.log10(self.high))
        return (self.low, self.high)

    def decode(self, x: float) -> float:
        v = 10.0**x if self.log else x
        return min(max(v, self.low), self.high)

    def encode(self, v: float) -> float:
        return math.log10(v) if self.log else v


SFM_PARAMS = [
    Param("tau", "force", 0.2, 2.0, True),
    Param("a_ped", "force", 0.1, 10.0, True),
    Param("b_ped", "force", 0.1, 3.0, True),
    Param("a_veh", "force", 0.1, 10.0, True),
    Param("b_veh", "force", 0.1, 3.0, True),
]
RA_PARAMS = SFM_PARAMS + [
    Param("lambda3", "force", 0.0, 5.0, False),
    Param("gamma1", "risk", 0.0, 2.0, False),
    Param("gamma2", "risk", 0.1, 3.0, True),
]
CR_PARAMS = RA_PARAMS + [
    Param("lambda1", "force", 0.0, 5.0, False),
    Param("lambda2", "force", 0.0, 5.0, False),
]


def _space(model: dict) -> list[Param]:
    """The parameters calibrated for a social-force model, from how it weighs its forces: the
    SFM's always, the risk parameters and ``lambda3`` when its weights use ``psi``, ``lambda1``
    and ``lambda2`` when they use ``u``."""
    if model["cognitive"]:
        return CR_PARAMS
    return RA_PARAMS if model["risk"] else SFM_PARAMS


#: The search space of every social-force model (sim-core's list, sharedspace.models).
SPACES: dict[str, list[Param]] = {m["name"]: _space(m) for m in MODELS if m["social_force"]}

# model.md section 5 starting values (and WorldParams::default() for the risk parameters).
STARTING_VALUES = {
    "tau": 0.5,
    "a_ped": 2.1,
    "b_ped": 0.3,
    "a_veh": 4.0,
    "b_veh": 1.0,
    "lambda1": 1.0,
    "lambda2": 1.0,
    "lambda3": 1.0,
    "gamma1": 0.5,
    "gamma2": 1.0,
}


def params_doc(model: str, values: dict[str, float]) -> dict:
    """The eval-peds parameter document that sets ``values`` for ``model`` only."""
    force = {p.name: values[p.name] for p in SPACES[model] if p.section == "force"}
    risk = {p.name: values[p.name] for p in SPACES[model] if p.section == "risk"}
    doc: dict = {"pedestrians": {model: force}}
    if risk:
        doc["models"] = {model: {"risk": risk}}
    return doc


class BatchEvaluator:
    """One ``sim-server eval-peds --batch`` process; each call sends a parameter line and reads
    the result line."""

    def __init__(
        self,
        server: Path,
        split: str,
        models: list[str],
        pool: Path | None = None,
        params: Path | None = None,
    ):
        cmd = [str(server), "eval-peds", "--batch", "--split", split, "--models", ",".join(models)]
        if pool is not None:
            cmd += ["--pool", str(pool)]
        # Calibration starts from model.md's values (`spec`), never from the shipped (calibrated)
        # defaults the binary uses without --params.
        cmd += ["--params", str(params) if params is not None else "spec"]
        self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, bufsize=1)
        self.evaluations = 0

    def __call__(self, doc: dict) -> dict:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(json.dumps(doc) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"eval-peds exited with status {self.proc.wait()}")
        self.evaluations += 1
        result = json.loads(line)
        if "error" in result:
            raise ValueError(result["error"])
        return result["models"]

    def close(self) -> None:
        if self.proc.stdin:
            self.proc.stdin.close()
        self.proc.wait(timeout=30)

    def __enter__(self) -> BatchEvaluator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def run_json(cmd: list[str]) -> dict:
    """Runs a command that prints one JSON document and returns it."""
    out = subprocess.run(cmd, check=True, capture_output=True, text=True)
    return json.loads(out.stdout)
