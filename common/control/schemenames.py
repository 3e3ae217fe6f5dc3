"""The names of the registered control schemes, read from their entry points without importing one.

:mod:`bipedtele.control.config` checks ``[control] scheme`` against them; the schemes
themselves (which take a :class:`~bipedtele.control.config.ControlConfig`) are in
:mod:`bipedtele.control.schemes`.
"""

from __future__ import annotations

from importlib import metadata

__all__ = ["ENTRY_POINT_GROUP", "registered", "scheme_names"]

#: Entry-point group that registers schemes (name -> Scheme subclass).
ENTRY_POINT_GROUP = "bipedtele.schemes"


def registered() -> dict[str, metadata.EntryPoint]:
    """Return the schemes' entry points by name (nothing is imported)."""
    return {ep.name: ep for ep in metadata.entry_points(group=ENTRY_POINT_GROUP)}


def scheme_names() -> list[str]:
    """Return the registered schemes' names, the paper's first, then sorted."""
    names = sorted(registered())
    return (["paper"] if "paper" in names else []) + [n for n in names if n != "paper"]
