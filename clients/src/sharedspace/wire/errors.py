"""Exceptions of the sharedspace client (protocol/SPEC.md section 4).

Every exception the package raises on purpose derives from :class:`SharedspaceError`.
An error reply of the server becomes a :class:`ServerError`, or the subclass registered for its
code (an unknown code gives a plain :class:`ServerError`, as the spec treats it like
``internal``).
"""

from __future__ import annotations

from sharedspace.cli import UserError


class SharedspaceError(Exception):
    """Base class of every sharedspace client error."""


class ProtocolError(SharedspaceError):
    """A payload that does not follow the wire protocol (undecodable, bad envelope, bad array)."""


class NoServer(SharedspaceError, UserError):
    """No server answered at ``endpoint`` within ``timeout`` seconds: most often a wrong
    endpoint or key prefix, so a command line says it in one line (:mod:`sharedspace.cli`)."""

    def __init__(self, endpoint: str, timeout: float | None = None, message: str | None = None):
        self.endpoint = endpoint
        self.timeout = timeout
        if message is None:
            message = f"no sharedspace server answered on {endpoint!r}"
            if timeout is not None:
                message += f" within {timeout:g} s"
        super().__init__(message)


class ServerError(SharedspaceError):
    """An ``{"error": {code, message, env_id}}`` reply of the server."""

    #: The error code this class stands for (``None``: any code).
    CODE: str | None = None

    def __init__(self, code: str, message: str, env_id: str | None = None):
        self.code = code
        self.message = message
        self.env_id = env_id
        text = f"[{code}] {message}"
        if env_id is not None:
            text += f" (env {env_id})"
        super().__init__(text)

    def __reduce__(self):
        return (_rebuild_server_error, (type(self), self.code, self.message, self.env_id))


def _rebuild_server_error(cls, code, message, env_id):
    return cls(code, message, env_id)


class BadRequest(ServerError):
    CODE = "bad_request"


class VersionMismatch(ServerError):
    CODE = "version_mismatch"


class UnknownEnv(ServerError):
    CODE = "unknown_env"


class EnvClosed(ServerError):
    CODE = "env_closed"


class NonFiniteAction(ServerError):
    CODE = "non_finite_action"


class WrongShape(ServerError):
    """The server's ``wrong_shape``; also raised client-side for actions of the wrong shape."""

    CODE = "wrong_shape"

    def __init__(self, code: str = "wrong_shape", message: str = "", env_id: str | None = None):
        super().__init__(code, message, env_id)


class LimitExceeded(ServerError):
    CODE = "limit_exceeded"


class NeedsReset(ServerError):
    CODE = "needs_reset"


class WrongMode(ServerError):
    CODE = "wrong_mode"


class InternalError(ServerError):
    CODE = "internal"


#: Error code -> exception class.
ERROR_CLASSES: dict[str, type[ServerError]] = {
    cls.CODE: cls
    for cls in (
        BadRequest,
        VersionMismatch,
        UnknownEnv,
        EnvClosed,
        NonFiniteAction,
        WrongShape,
        LimitExceeded,
        NeedsReset,
        WrongMode,
        InternalError,
    )
}


def server_error(code: str, message: str, env_id: str | None = None) -> ServerError:
    """The exception for an error reply with ``code`` (a plain ServerError for unknown codes)."""
    cls = ERROR_CLASSES.get(code, ServerError)
    return cls(code, message, env_id)
