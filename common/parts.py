"""Registered parts: robots, leader devices and operator models, one entry point each.

A part is one object (a :class:`Part`, or a role's subclass of it that adds the part's
capability flags) found through an entry-point group of the installed distributions::

    [project.entry-points."bipedtele.robots"]
    toy = "toy_robot:PART"

That entry point is the only list: the command line's choices, the profile's check of a
name, the profile section the part brings (:attr:`Part.config`, registered with the
profile's sections) and the object the program builds all come from it. The module an
entry point names is loaded when a profile is loaded, so it stays light: a driver that
needs a heavy package imports it inside :attr:`Part.build`.

The core defines the registry; each role keeps its own (``bipedtele.follower.robot.ROBOTS``,
``bipedtele.leader.device.DEVICES``, ``bipedtele.leader.operator.OPERATORS``), so the core
imports neither role. The recipe: ``docs/architecture.md``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from importlib import metadata
from typing import Any, Generic, TypeVar

__all__ = ["PART_GROUPS", "Part", "PartError", "Parts", "lazy", "part_sections"]

#: The entry-point groups of the parts, by kind (the profile's sections come from all three).
PART_GROUPS: dict[str, str] = {
    "robot": "bipedtele.robots",
    "device": "bipedtele.devices",
    "operator": "bipedtele.operators",
}


class PartError(TypeError):
    """An entry point of a part group names something that is not a part of that kind."""


@dataclass(frozen=True)
class Part:
    """One implementation the programs offer.

    Attributes
    ----------
    name : str
        Its name (``--robot``, ``--device``, ``--operator``); equal to its entry point's.
    doc : str
        One line for the help.
    build : callable
        ``build(**kwargs)`` returns the implementation; the keywords are the role's
        (``config=`` for robots and devices, the operator's context for operators).
    section : str or None
        The profile section that configures it; None: it has none of its own.
    config : type or None
        That section's dataclass when the part brings it (registered with the profile's
        sections under :attr:`section`); None when the section is another's.
    """

    name: str
    doc: str
    build: Callable[..., Any]
    section: str | None = None
    config: type | None = None


def lazy(target: str) -> Callable[..., Any]:
    """Return a builder that imports ``module:attr`` on its first call and calls it with the same arguments.

    For a part whose driver must not load with every profile (pybullet, a device library):
    ``build=lazy("bipedtele.follower.sim.robot:SimNao")``.
    """
    module, _, attr = target.partition(":")

    def build(*args: Any, **kwargs: Any) -> Any:
        return getattr(importlib.import_module(module), attr)(*args, **kwargs)

    build.__qualname__ = build.__name__ = f"lazy({target})"
    return build


P = TypeVar("P", bound=Part)


class Parts(Generic[P]):
    """The parts of one kind: the entry points of ``group``.

    Parameters
    ----------
    kind : str
        What it holds (``robot``, ``device``, ``operator``), for messages.
    group : str
        The entry-point group.
    part_type : type
        The class every entry point must name an instance of.
    """

    def __init__(self, kind: str, group: str, part_type: type[P]) -> None:
        self.kind = kind
        self.group = group
        self.part_type = part_type
        self._loaded: dict[str, P] = {}

    def names(self) -> list[str]:
        """Return the registered names, sorted (read from the entry points: nothing is imported)."""
        return sorted({ep.name for ep in metadata.entry_points(group=self.group)})

    def get(self, name: str) -> P:
        """Return the part registered as ``name``.

        Raises
        ------
        ValueError
            No such name; the message lists the allowed ones.
        PartError
            Its entry point names something else than a part of this kind, or a part of
            another name; or two distributions register the name.
        """
        if name in self._loaded:
            return self._loaded[name]
        eps = [ep for ep in metadata.entry_points(group=self.group) if ep.name == name]
        if not eps:
            raise ValueError(f"{self.kind} {name!r}: allowed: {', '.join(self.names())}")
        if len({ep.value for ep in eps}) > 1:
            raise PartError(f"{self.kind} {name!r} is registered twice: {', '.join(sorted({ep.value for ep in eps}))}")
        part = eps[0].load()
        if not isinstance(part, self.part_type):
            raise PartError(f"entry point {self.group}:{name} = {eps[0].value} is not a {self.part_type.__name__}")
        if part.name != name:
            raise PartError(f"entry point {self.group}:{name} = {eps[0].value} names the {self.kind} {part.name!r}")
        self._loaded[name] = part
        return part

    def build(self, name: str, **kwargs: Any) -> Any:
        """Build the implementation registered as ``name`` (see :meth:`get`)."""
        return self.get(name).build(**kwargs)

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and name in self.names()

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())


def part_sections() -> dict[str, type]:
    """Return the profile sections the registered parts bring: section name -> dataclass.

    Loads every part's module (they are light by contract).

    Raises
    ------
    PartError
        Two parts bring different classes for one section.
    """
    found: dict[str, type] = {}
    for group in PART_GROUPS.values():
        for ep in metadata.entry_points(group=group):
            part = ep.load()
            cls = getattr(part, "config", None)
            section = getattr(part, "section", None)
            if cls is None or section is None:
                continue
            if found.setdefault(section, cls) is not cls:
                raise PartError(f"section [{section}]: {ep.value} brings another class than {found[section]!r}")
    return found
