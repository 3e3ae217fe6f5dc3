"""Make this interpreter lack what Windows lacks, for the leader's portability test.

Loaded by every Python process started with this folder on ``PYTHONPATH`` (the leader and
its cockpit's child process). Imports of the modules named in ``BIPEDTELE_BLOCK``
(comma-separated top-level names: evdev, fcntl, termios, resource, ...) fail with
ModuleNotFoundError as on Windows, and ``os.nice`` is gone. Each attempt is appended, one
name per line, to ``BIPEDTELE_BLOCK_LOG`` when set.
"""

from __future__ import annotations

import importlib.abc
import os
import sys

_BLOCKED = {m for m in os.environ.get("BIPEDTELE_BLOCK", "").split(",") if m}
_LOG = os.environ.get("BIPEDTELE_BLOCK_LOG", "")


class _Blocked(importlib.abc.MetaPathFinder):
    def find_spec(self, name: str, path: object = None, target: object = None) -> None:
        if name.split(".")[0] in _BLOCKED:
            if _LOG:
                with open(_LOG, "a", encoding="utf-8") as f:
                    f.write(f"{name}\n")
            raise ModuleNotFoundError(f"No module named {name!r} (blocked: not on this platform)", name=name)


if _BLOCKED:
    for _name in list(sys.modules):
        if _name.split(".")[0] in _BLOCKED:
            del sys.modules[_name]
    sys.meta_path.insert(0, _Blocked())
    if hasattr(os, "nice"):
        del os.nice
