"""The back-ends a role registers for the core's tools (the walker's study and compare cells).

The core never imports the follower: ``bipedtele study --walker`` and ``bipedtele compare``'s
walker cells find the follower's code through the entry-point groups
``bipedtele.study_backends`` and ``bipedtele.compare_backends``.
"""

from __future__ import annotations

from importlib import metadata
from typing import Any

from bipedtele.config.profile import ConfigError

__all__ = ["walker_backend"]


def walker_backend(group: str, option: str, allowed: str) -> Any:
    """Return the ``walker`` back-end registered under ``group`` (loaded).

    Raises
    ------
    ConfigError
        None is installed: one line naming ``option`` and what is ``allowed``.
    """
    for ep in metadata.entry_points(group=group):
        if ep.name == "walker":
            return ep.load()
    raise ConfigError(f"{option}: no walker backend installed; allowed: {allowed}")
