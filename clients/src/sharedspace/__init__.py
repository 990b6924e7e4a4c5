"""sharedspace: Python clients of the sharedspace AV/pedestrian simulation server.

- :mod:`sharedspace.codec`: MessagePack wire codec (protocol/SPEC.md);
- :mod:`sharedspace.errors`: the exceptions;
- :mod:`sharedspace.models`: the pedestrian models (sim-core's one list);
- :mod:`sharedspace.pool`: scenario pools and what their records say;
- :mod:`sharedspace.local_server`: ``sim-server`` on this machine (a local server, a rollout);
- :mod:`sharedspace.transport`: the zenoh session, server discovery, liveliness;
- :mod:`sharedspace.decode`: the server's messages decoded into NumPy arrays;
- :mod:`sharedspace.client`: :class:`SimClient`, one connection to a server;
- :mod:`sharedspace.vector`: the batched :class:`VectorClient` (failover);
- :mod:`sharedspace.pettingzoo_env`: :func:`parallel_env`, a PettingZoo ``ParallelEnv``, and
  :func:`env`, the same as an AEC env;
- :mod:`sharedspace.gym_env`: ``SharedSpaceEnv``, registered with Gymnasium as
  ``sharedspace/SharedSpace-v0`` on import;
- :mod:`sharedspace.torchrl_env`: ``RemoteBatchedEnv`` (imported lazily: needs torch/torchrl);
- :mod:`sharedspace.torchrl_multiagent`: ``RemoteMultiAgentEnv``, several cars per scene (lazily);
- :mod:`sharedspace.observer`: :class:`Observer` of the envs' publications.
"""

from .errors import (
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
    "SimClient": ("client", "SimClient"),
    "VectorClient": ("vector", "VectorClient"),
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
    "Observer",
    "parallel_env",
    "env",
    "SharedSpaceParallelEnv",
    "RemoteBatchedEnv",
    "RemoteMultiAgentEnv",
    "SharedSpaceEnv",
    "__version__",
]
