"""Named registries of implementations (robots, devices), filled by class decorators.

``bipedtele.follower`` keeps one for robots and ``bipedtele.leader`` one for devices; both
are instances of :class:`Registry`, so a new robot or device registers itself exactly like
the built-in ones (the LeRobot pattern: fakes and real parts register alike).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterator
from typing import Any, Generic, TypeVar

__all__ = ["Registry"]

T = TypeVar("T")
C = TypeVar("C", bound=type)


class Registry(Generic[T]):
    """Name -> class of one kind of implementation.

    Parameters
    ----------
    kind : str
        What it holds (``robot``, ``device``), for messages.
    builtins : str
        Module whose import registers the built-in implementations; imported on the
        first :meth:`make` so that importing the contract alone stays cheap.
    """

    def __init__(self, kind: str, builtins: str) -> None:
        self.kind = kind
        self._builtins = builtins
        self._classes: dict[str, Callable[..., T]] = {}

    def register(self, name: str) -> Callable[[C], C]:
        """Class decorator: register the class under ``name`` and set its ``name``."""

        def deco(cls: C) -> C:
            setattr(cls, "name", name)  # noqa: B010 (C is any class)
            self._classes[name] = cls
            return cls

        return deco

    def make(self, name: str, **kwargs: Any) -> T:
        """Instantiate the implementation registered as ``name``.

        Raises
        ------
        ValueError
            No such name; the message lists the allowed ones.
        """
        importlib.import_module(self._builtins)
        try:
            factory = self._classes[name]
        except KeyError:
            raise ValueError(f"{self.kind} {name!r}: allowed: {', '.join(sorted(self._classes))}") from None
        return factory(**kwargs)

    def __contains__(self, name: object) -> bool:
        return name in self._classes

    def __getitem__(self, name: str) -> Callable[..., T]:
        return self._classes[name]

    def __iter__(self) -> Iterator[str]:
        return iter(sorted(self._classes))
