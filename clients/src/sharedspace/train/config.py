"""Training configuration: one dataclass, loadable from TOML/JSON plus ``key=value`` overrides."""

from __future__ import annotations

import argparse
import dataclasses
import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sharedspace.client import Connection
from sharedspace.models import DEFAULT_MODEL
from sharedspace.scripted import SCRIPTED
from sharedspace.wire import EnvSpec

__all__ = ["VARIANTS", "TrainConfig", "load_config", "apply_overrides"]

#: Network variants (paper Section V.B): G-SAC-Cog, G-SAC-NoCog, S-SAC.
VARIANTS = ("g_sac_cog", "g_sac_nocog", "s_sac")
#: Fields of older configs, ignored when one is loaded (``env_backend``: the Rust server is
#: the only backend).
RETIRED_FIELDS = ("env_backend",)


@dataclass
class TrainConfig:
    """Every knob of a SAC(-GCN) run. One line of doc per field."""

    # --- run
    seed: int = 0  # seed of torch, numpy and the env's scenario sequence
    variant: str = (
        "g_sac_cog"  # g_sac_cog (A = env risk graph) | g_sac_nocog (uniform) | s_sac (MLP)
    )
    total_frames: int = 200_000  # env transitions to collect (summed over the K sub-envs)
    device: str = "cpu"  # torch device of the networks and the updates ("cpu", "cuda")
    num_threads: int = 1  # torch CPU threads (0 = torch's default; 1 is fastest on shared cores)
    # --- env
    num_envs: int = 8  # K, sub-envs stepped together (env batch size)
    max_agents: int = 8  # M, graph nodes per observation (ego + M-1 nearest agents)
    pedestrian_model: str = DEFAULT_MODEL  # model of the simulated crowd (sharedspace.models)
    scenario_pool: str = ""  # scenario file path; "" = scenarios/data/hbs-paper.json
    server_endpoint: str = ""  # Zenoh endpoint of the server; "" = start a local sim-server
    server_params: str = ""  # world-parameter file of that local server; "" = its defaults
    server_prefix: str = "sharedspace"  # Zenoh key prefix of the server
    zenoh_config: str = ""  # trainer session file (deploy/trainer.json5); "" = peer on endpoint
    variations: dict[str, Any] = field(
        default_factory=dict
    )  # scene variations of the training envs (SPEC 5.2.1; JSON on --set); {} = none
    vehicle_model: str = ""  # cars nobody controls: replay | idm (reactive); "" = the pool's
    reward_weights: dict[str, float] = field(
        default_factory=dict
    )  # reward weights over the world's (SPEC 8.2 names; JSON on --set); {} = the world's
    # --- SAC
    frames_per_batch: int = 0  # frames per collector batch; 0 = num_envs * 8
    init_random_frames: int = 5_000  # frames collected by a uniform random policy first
    utd_ratio: float = 0.5  # gradient updates per collected frame
    batch_size: int = 256  # replay minibatch size
    buffer_size: int = 200_000  # replay buffer capacity (transitions)
    lr: float = 3e-4  # Adam learning rate of actor, critics and temperature
    gamma: float = 0.99  # discount factor
    tau: float = 0.005  # soft target update coefficient (theta' <- tau theta + (1-tau) theta')
    alpha_init: float = 1.0  # initial entropy temperature (learned, target entropy = -|A|)
    loss_function: str = "l2"  # critic loss: l2 | smooth_l1
    critic_layer_norm: bool = False  # LayerNorm after each hidden layer of the critics (RLPD)
    base_driver: str = ""  # scripted driver the actor's action adds to (residual); "" = none
    critic_warmup: int = 0  # gradient updates of the critics alone before actor and alpha learn
    # --- prior data (RLPD, Ball et al. 2023; sharedspace.train.prior, `make demos`)
    prior_data: str = ""  # dataset directory of recorded transitions; "" = online data only
    prior_sources: str = ""  # comma-separated sources of it to use (e.g. car_aware); "" = all
    prior_successes_only: bool = False  # only the transitions of episodes that reached the goal
    prior_ratio: float = 0.5  # share of every replay batch drawn from the prior data
    bc_weight: float = (
        0.0  # TD3+BC term (x mean|Q|) in the actor loss (prior rows; or to base); 0 off
    )
    bc_steps: int = 0  # behaviour-cloning steps of the actor on the prior data before collecting
    # --- networks
    hidden_sizes: list[int] = field(default_factory=lambda: [256, 256])  # MLP head widths
    gcn_hidden: int = 64  # width of each GCN layer's output
    gcn_layers: int = 2  # number of GCN layers (ignored by s_sac)
    readout: str = "ego_mean"  # graph readout: "ego" (node 0) | "ego_mean" (node 0 ++ mean)
    # --- evaluation, logging, checkpoints
    eval_interval: int = 20_000  # frames between evaluations on the test split (0 = never)
    eval_split: str = "test"  # split evaluated during training
    eval_envs: int = 18  # sub-envs of the evaluation env (18 = every test scenario at once)
    checkpoint_interval: int = 50_000  # frames between checkpoints (0 = only at the end)
    save_buffer: bool = False  # include the replay buffer in checkpoints
    log_dir: str = "runs/default"  # run directory: metrics.csv, TensorBoard events, checkpoints
    progress: bool = True  # show a tqdm progress bar

    def __post_init__(self):
        if self.variant not in VARIANTS:
            raise ValueError(f"variant must be one of {VARIANTS}, not {self.variant!r}")
        self.env_spec("train", self.seed, self.variations)  # names a wrong env field now
        if self.readout not in ("ego", "ego_mean"):
            raise ValueError(f"readout must be ego or ego_mean, not {self.readout!r}")
        if self.base_driver and self.base_driver not in SCRIPTED:
            raise ValueError(f"base_driver must be one of {sorted(SCRIPTED)} or empty")
        if not 0.0 <= self.prior_ratio < 1.0:
            raise ValueError(f"prior_ratio must be in [0, 1), not {self.prior_ratio}")
        if self.bc_steps > 0 and not self.prior_data:
            raise ValueError("bc_steps clone the prior data: set prior_data")
        if self.bc_weight > 0 and not (self.prior_data or self.base_driver):
            raise ValueError("bc_weight imitates the prior data or the base driver: set one")

    def env_spec(self, split: str, seed: int, variations: dict[str, Any] | None = None) -> EnvSpec:
        """The envs this config trains or evaluates on: ``split``, ``seed`` and scene
        ``variations`` (the training env's are ``variations``; evaluation plays the scenes)."""
        return EnvSpec(
            pool=self.scenario_pool or None,
            split=split,
            seed=seed,
            pedestrian_model=self.pedestrian_model,
            max_agents=self.max_agents,
            variations=variations or None,
            vehicle_model=self.vehicle_model or None,
            reward_weights=dict(self.reward_weights),
        )

    def connection(self) -> Connection:
        """Where the envs live (:meth:`sharedspace.client.Connection.resolve`): the zenoh file,
        else the endpoint, else a local ``sim-server`` of this config's pool and parameters."""
        return Connection.resolve(
            self.server_endpoint,
            self.server_prefix,
            self.zenoh_config,
            [self.scenario_pool] if self.scenario_pool else [],
            self.server_params or None,
        )

    @classmethod
    def from_dict(cls, fields: dict[str, Any]) -> TrainConfig:
        """A config from a saved one (a checkpoint's, ``config.json``), without the fields
        configs no longer have (:data:`RETIRED_FIELDS`)."""
        return cls(**{k: v for k, v in fields.items() if k not in RETIRED_FIELDS})

    @property
    def batch_frames(self) -> int:
        """Frames per collector batch."""
        return self.frames_per_batch or self.num_envs * 8

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def _parse_value(text: str, like: Any) -> Any:
    if isinstance(like, bool):
        if text.lower() in ("1", "true", "yes", "on"):
            return True
        if text.lower() in ("0", "false", "no", "off"):
            return False
        raise ValueError(f"not a boolean: {text!r}")
    if isinstance(like, int):
        return int(float(text)) if "e" in text.lower() else int(text)
    if isinstance(like, float):
        return float(text)
    if isinstance(like, list):
        return [int(x) for x in text.strip("[]").split(",") if x.strip()]
    if isinstance(like, dict):
        value = json.loads(text) if text.strip() else {}
        if not isinstance(value, dict):
            raise ValueError(f"expected a JSON object, got {text!r}")
        return value
    return text


def apply_overrides(cfg: TrainConfig, overrides: list[str] | dict[str, Any]) -> TrainConfig:
    """A copy of ``cfg`` with ``key=value`` strings (or a dict) applied; values are parsed by
    the field's type (lists as ``256,256``)."""
    data = cfg.to_dict()
    items = (
        overrides.items() if isinstance(overrides, dict) else (o.split("=", 1) for o in overrides)
    )
    for key, value in items:
        key = key.strip()
        if key in RETIRED_FIELDS:
            continue
        if key not in data:
            raise KeyError(f"unknown config key {key!r}")
        data[key] = _parse_value(value, data[key]) if isinstance(value, str) else value
    return TrainConfig.from_dict(data)


def command_parser(prog: str, doc: str | None) -> argparse.ArgumentParser:
    """The argument parser of a ``python -m`` command: its module docstring ``doc`` as the
    description, printed as written."""
    return argparse.ArgumentParser(
        prog=prog, description=doc, formatter_class=argparse.RawDescriptionHelpFormatter
    )


def add_overrides_argument(
    ap, help: str = "TrainConfig overrides, e.g. server_endpoint=..."
) -> None:
    """The ``--set KEY=VALUE ...`` option every ``sharedspace.train`` command takes (repeatable;
    values parsed like the field they override)."""
    ap.add_argument("--set", nargs="*", action="extend", default=[], metavar="KEY=VALUE", help=help)


def load_config(path: str | Path | None = None, overrides: list[str] | None = None) -> TrainConfig:
    """Defaults, then the TOML/JSON file at ``path`` (flat table of fields), then overrides."""
    cfg = TrainConfig()
    if path:
        cfg = apply_overrides(cfg, _read_table(path))
    return apply_overrides(cfg, overrides or [])


def _read_table(path: str | Path) -> dict[str, Any]:
    p = Path(path)
    return tomllib.loads(p.read_text()) if p.suffix == ".toml" else json.loads(p.read_text())
