"""How every command line meets a user's mistake: one line that names it on stderr, exit status
2, no traceback. ``--debug`` on the command line (or ``SHAREDSPACE_DEBUG=1``) shows the
traceback instead.

A user's mistake is a :class:`UserError` (a wrong config key or value, an unknown task,
network, algorithm or driver, a file that is not a checkpoint: each package's own error class
derives from it) or a file that is not there. Anything else is a defect and keeps its
traceback.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import os
import sys
from collections.abc import Callable, Iterable, Sequence
from typing import Any

__all__ = ["UserError", "declared_default", "did_you_mean", "parse_value", "run_command"]


class UserError(ValueError):
    """A mistake in what a user asked for; its message names what was wrong."""


def did_you_mean(name: str, choices: Iterable[str]) -> str:
    """`` (did you mean 'x'?)`` for the choice closest to ``name``, or "" when none is close."""
    close = difflib.get_close_matches(name, list(choices), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def run_command(main: Callable[[Sequence[str] | None], int], argv: Sequence[str] | None = None):
    """``main(argv)`` with a user's mistake turned into one line and exit status 2; returns
    ``main``'s status otherwise. ``--debug`` (removed before ``main`` sees the words) or
    ``SHAREDSPACE_DEBUG=1`` lets the traceback through."""
    words = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in words or os.environ.get("SHAREDSPACE_DEBUG", "") not in ("", "0")
    words = [w for w in words if w != "--debug"]
    try:
        return main(words)
    except (UserError, FileNotFoundError) as err:
        if debug:
            raise
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        print(f"error: {first}", file=sys.stderr)
        return 2


def parse_value(key: str, text: str, like: Any, error: type[Exception] = UserError) -> Any:
    """``text`` parsed as the type of ``like`` (the field's current value): booleans as
    true/false/1/0/yes/no/on/off, integers (``1e4`` too), floats, lists as ``256,256`` or
    ``[256, 256]``, dicts as JSON objects; anything else is the string. A value that does not
    parse is an ``error`` naming ``key``."""
    try:
        if isinstance(like, bool):
            if text.lower() in ("1", "true", "yes", "on"):
                return True
            if text.lower() in ("0", "false", "no", "off"):
                return False
            raise ValueError("not a boolean")
        if isinstance(like, int):
            return int(float(text)) if "e" in text.lower() else int(text)
        if isinstance(like, float):
            return float(text)
        if isinstance(like, list):
            return [int(x) for x in text.strip("[]").split(",") if x.strip()]
        if isinstance(like, dict):
            value = json.loads(text) if text.strip() else {}
            if not isinstance(value, dict):
                raise ValueError("not a JSON object")
            return value
    except ValueError as exc:
        raise error(f"--set {key}={text}: expected {type(like).__name__} ({exc})") from None
    return text


def declared_default(cls: type, name: str) -> Any:
    """The default the dataclass ``cls`` declares for its field ``name`` (a fresh copy of a
    factory's): what a config key takes when it is not given, and what a value is parsed like."""
    f = cls.__dataclass_fields__[name]
    return f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
