"""sharedspace: Python clients of the sharedspace AV/pedestrian simulation server.

Layers, each importing only those below it (``.importlinter`` checks it):

- wire: :mod:`sharedspace.wire` (envelope and arrays, requests with :class:`EnvSpec`, replies,
  errors), over :mod:`sharedspace.names` and :mod:`sharedspace.models` (sim-core's lists);
- client: :mod:`sharedspace.transport` (the zenoh session, discovery, liveliness),
  :mod:`sharedspace.client` (:class:`SimClient`, :class:`Connection`),
  :mod:`sharedspace.vector` (the batched :class:`VectorClient`, failover),
  :mod:`sharedspace.local_server` (``sim-server`` on this machine), :mod:`sharedspace.pool`,
  :mod:`sharedspace.observer` (:class:`Observer` of the envs' publications);
- envs: :mod:`sharedspace.pettingzoo_env` (:func:`parallel_env`, :func:`env`),
  :mod:`sharedspace.gym_env` (``sharedspace/SharedSpace-v0``, registered on import),
  :mod:`sharedspace.torchrl_env` (``RemoteBatchedEnv``), :mod:`sharedspace.torchrl_multiagent`
  (``RemoteMultiAgentEnv``), and the pictures they draw (render, scene_plot, spaces);
- :mod:`sharedspace.train`: the SAC-GCN trainer (``python -m sharedspace.train``);
- :mod:`sharedspace.paper`: the paper's tooling (evaluation, powered test, tables, planner,
  scripted drivers, plots), and :mod:`sharedspace.viewer`, the live viewer.
"""

from .wire import EnvSpec
from .wire.errors import (
    EnvClosed,
    NoServer,
    ProtocolError,
    ServerError,
    SharedspaceError,
    VersionMismatch,
    WrongShape,
)

__version__ = "0.1.0"

_LAZY = {
    "ServerLost": ("transport", "ServerLost"),
    "Transport": ("transport", "Transport"),
    "Connection": ("client", "Connection"),
    "SimClient": ("client", "SimClient"),
    "VectorClient": ("vector", "VectorClient"),
    "LocalServer": ("local_server", "LocalServer"),
    "RemoteMultiAgentEnv": ("torchrl_multiagent", "RemoteMultiAgentEnv"),
    "Observer": ("observer", "Observer"),
    "parallel_env": ("pettingzoo_env", "parallel_env"),
    "env": ("pettingzoo_env", "env"),
    "SharedSpaceParallelEnv": ("pettingzoo_env", "SharedSpaceParallelEnv"),
    "RemoteBatchedEnv": ("torchrl_env", "RemoteBatchedEnv"),
    "SharedSpaceEnv": ("gym_env", "SharedSpaceEnv"),
}

# `gymnasium.make("sharedspace/SharedSpace-v0")` after `import sharedspace` (gymnasium is a
# dependency of the package).
from .gym_env import register as _register_gym  # noqa: E402

_register_gym()


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        module, attr = _LAZY[name]
        return getattr(importlib.import_module(f".{module}", __name__), attr)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "EnvSpec",
    "Connection",
    "SharedspaceError",
    "ServerError",
    "ProtocolError",
    "VersionMismatch",
    "EnvClosed",
    "WrongShape",
    "NoServer",
    "ServerLost",
    "Transport",
    "SimClient",
    "VectorClient",
    "LocalServer",
    "Observer",
    "parallel_env",
    "env",
    "SharedSpaceParallelEnv",
    "RemoteBatchedEnv",
    "RemoteMultiAgentEnv",
    "SharedSpaceEnv",
    "__version__",
]
