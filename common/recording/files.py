"""Recording files: their names and their opening for a run (the :class:`~bipedtele.recording.recorder.Recorder` writes them).

:func:`new_recording_path` gives ``FOLDER/ROLE-YYYYmmdd-HHMMSS-mmm.mcap`` (local time to the
millisecond; ``-1``, ``-2``, ... appended when taken). The recorder creates its file
exclusively (it never overwrites one) and, when closed without a single message recorded,
removes it, so a run that failed at start leaves no empty file behind.
:func:`open_recording` combines the two and retries with the next name if another process
took the same one in between; :func:`recording_for_run` is the programs' entry (``--record``
or a new file in ``[record] dir``).
"""

from __future__ import annotations

import re
import time
from pathlib import Path
from typing import Any

from bipedtele.recording.recorder import Recorder

__all__ = ["new_recording_path", "open_recording", "recording_for_run"]

_ROLE = re.compile(r"^[A-Za-z0-9_]+(?:-[A-Za-z0-9_]+)*$")
_MAX_SUFFIX = 10_000


def new_recording_path(folder: str | Path, role: str, *, now: float | None = None) -> Path:
    """Return a recording file name in ``folder`` that no file has yet.

    ``FOLDER/ROLE-YYYYmmdd-HHMMSS-mmm.mcap`` (local time, milliseconds); when that name
    is taken, ``-1``, ``-2``, ... is appended before ``.mcap``. The file is not created:
    :class:`Recorder` creates it exclusively, so two processes that got the same name
    cannot overwrite each other (the second gets ``FileExistsError``; see
    :func:`open_recording`, which then takes the next name).

    Parameters
    ----------
    folder : str or Path
        Folder of the recordings (need not exist yet).
    role : str
        ``leader``, ``follower``, ...: letters, digits, ``_`` and inner ``-``.
    now : float, optional
        The time to stamp [s since the epoch]; ``time.time()`` when omitted.

    Raises
    ------
    ValueError
        ``role`` is not a plain name.
    """
    if not _ROLE.match(role):
        raise ValueError(f"role {role!r}: allowed: letters, digits, '_' and inner '-'")
    t = time.time() if now is None else now
    ms = int((t % 1.0) * 1000)
    stem = f"{role}-{time.strftime('%Y%m%d-%H%M%S', time.localtime(t))}-{ms:03d}"
    folder = Path(folder)
    path = folder / f"{stem}.mcap"
    n = 0
    while path.exists():
        n += 1
        if n > _MAX_SUFFIX:
            raise FileExistsError(f"{folder}: {_MAX_SUFFIX} recordings named {stem}-*.mcap")
        path = folder / f"{stem}-{n}.mcap"
    return path


def open_recording(folder: str | Path, role: str, **kwargs: Any) -> Recorder:
    """Return a :class:`Recorder` on a new file :func:`new_recording_path` names in ``folder``.

    Creates ``folder`` if needed. If another process creates the same name between the
    choice and the exclusive creation, the next free name is taken.

    Parameters
    ----------
    folder : str or Path
        Folder of the recordings.
    role : str
        The file name's prefix (``leader``, ``follower``).
    **kwargs
        :class:`Recorder` parameters (``flush_s``, ``metadata``, ``jpeg_every``, ...).

    Raises
    ------
    OSError
        The folder or the file cannot be created.
    """
    Path(folder).mkdir(parents=True, exist_ok=True)
    for _ in range(100):
        try:
            return Recorder(new_recording_path(folder, role), **kwargs)
        except FileExistsError:
            continue
    raise FileExistsError(f"{folder}: no free recording name for {role!r} after 100 tries")


def recording_for_run(record: Path | None, folder: str | Path, role: str, **kwargs: Any) -> Recorder:
    """Return the recording of one program run: ``record`` when given, else a new file in ``folder``.

    Parameters
    ----------
    record : Path or None
        The file the user asked for (``--record``); it must not exist.
    folder : str or Path
        Folder of the recordings (``[record] dir``) when ``record`` is None.
    role : str
        The new file's name prefix (``leader``, ``follower``).
    **kwargs
        :class:`Recorder` parameters.

    Raises
    ------
    ConfigError
        ``record`` exists, or the folder or file cannot be created (one line, exit 2).
    """
    from bipedtele.config.profile import ConfigError

    try:
        if record is not None:
            record.parent.mkdir(parents=True, exist_ok=True)
            return Recorder(record, **kwargs)
        return open_recording(folder, role, **kwargs)
    except FileExistsError:
        raise ConfigError(f"--record {record}: the file exists; allowed: a new file (never overwritten)") from None
    except OSError as exc:
        raise ConfigError(
            f"recording {record or folder}: cannot create ({exc.strerror or exc}); allowed: a writable folder"
        ) from None
