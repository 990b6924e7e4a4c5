"""The one context-manager behaviour of the package's resources (transport, clients, observer,
viewer, local server): ``with x:`` calls ``x.close()`` on leaving the block."""

from __future__ import annotations

from typing import Self

__all__ = ["Closing"]


class Closing:
    """Base of a resource closed by ``close()``: ``with`` returns it and closes it at the end."""

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
