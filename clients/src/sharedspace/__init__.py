"""sharedspace: Python clients of the sharedspace AV/pedestrian simulation server.

- :mod:`sharedspace.codec`: MessagePack wire codec (protocol/SPEC.md);
- :mod:`sharedspace.errors`: the exceptions;
- :mod:`sharedspace.reference`: a pure-numpy reference of the world step (shared/spec/model.md).
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

__all__ = [
    "SharedspaceError",
    "ServerError",
    "ProtocolError",
    "VersionMismatch",
    "EnvClosed",
    "WrongShape",
    "NoServer",
    "__version__",
]
