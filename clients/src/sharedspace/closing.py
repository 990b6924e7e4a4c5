"""The one context-manager behaviour of the package's resources (transport, clients, observer,
viewer, local server): ``with x:`` calls ``x.close()`` on leaving the block."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Self

__all__ = ["Closing"]


class Closing(ABC):
    """Base of a resource closed by ``close()``: ``with`` returns it and closes it at the end."""

    @abstractmethod
    def close(self) -> None:
        """Releases the resource; each subclass says what that means."""

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
