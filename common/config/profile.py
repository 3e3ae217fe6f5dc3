"""Typed, validated configuration loaded from TOML profiles.

A profile is a TOML file with one table per *section*. Each section is a frozen
dataclass whose fields carry their allowed range in metadata (see :func:`param`). A
section is checked by msgspec: from each dataclass's annotations and ``param()`` ranges a
validator type is built once (``Annotated[float, msgspec.Meta(ge=..., le=...)]``,
``Literal``, lists, nested tables) and the table is converted with ``msgspec.convert``
in strict mode; numbers must also be finite, and a whole float (``2.0``) is taken for an
integer field.
Sections are registered by the part of the product that owns them through the
``bipedtele.config.profile`` entry-point group, so the core never imports the leader or the
follower, yet every section of a profile is validated by every process that loads it
(a typo in ``[leader]`` is caught by the follower too).

Errors are :class:`ConfigError`; their message is one line naming the file, the key,
the value and what is allowed. The CLI turns them into exit code 2.

Relative paths
--------------
A field declared with ``param(path=True)`` holds a file or folder. A relative path written
in a profile *file* given by its path (``--config host/bipedtele.toml``) is read relative to
that file's folder, so a folder holding a profile and the files it names can be copied
anywhere and used from any working folder. Paths in the profiles shipped in ``configs/``
(``--config intercontinental``) and in ``--set`` overrides stay relative to the working
folder of the process. ``~`` at the start of a path in a profile file is expanded.

Secrets
-------
:meth:`Config.to_dict` replaces secrets by ``"***"`` unless asked not to: fields declared
with ``param(secret=True)`` and any key whose name contains ``password``, ``passwd``,
``secret`` or ``token`` (except names of files, ``*_file``/``*_path``/``*_dir``, and fields
declared ``path=True``: a path to a secret is not the secret). ``bipedtele config`` and
the recordings' metadata use it, so neither ever carries a password.

Examples
--------
>>> cfg = load_config("default")            # a profile shipped in configs/
>>> cfg = load_config("my.toml", ["leader.cmd_rate_hz=50"])
>>> cfg.section("network").mode
'peer'
"""

from __future__ import annotations

import dataclasses
import os
import re
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from importlib import metadata, resources
from pathlib import Path
from typing import Any, TypeVar, get_type_hints

from bipedtele.config.fields import ConfigError, param
from bipedtele.config.parse import dataclass_of, fmt_value, parse_section
from bipedtele.config.sections import CORE_SECTIONS
from bipedtele.parts import part_sections

__all__ = [
    "REDACTED",
    "Config",
    "ConfigError",
    "load_config",
    "param",
    "parse_section",
    "profile_names",
    "register_section",
    "resolve_paths",
    "resolve_section",
    "section_classes",
]

T = TypeVar("T")


# --------------------------------------------------------------------------- registry

_REGISTRY: dict[str, type] = {}
_ENTRY_POINTS_LOADED = False


def register_section(name: str, cls: type) -> None:
    """Register a section dataclass under ``name`` (for sections outside entry points)."""
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"config section {name!r} must be a dataclass, got {cls!r}")
    _REGISTRY[name] = cls


def section_classes() -> dict[str, type]:
    """All known section classes: the core's plus those registered by entry points."""
    global _ENTRY_POINTS_LOADED
    if not _ENTRY_POINTS_LOADED:
        for name, cls in CORE_SECTIONS.items():  # the core's own sections
            _REGISTRY.setdefault(name, cls)
        for ep in metadata.entry_points(group="bipedtele.config.profile"):
            _REGISTRY.setdefault(ep.name, ep.load())
        for name, cls in part_sections().items():  # the sections robots, devices and operators bring
            _REGISTRY.setdefault(name, cls)
        _ENTRY_POINTS_LOADED = True
    return dict(_REGISTRY)


# --------------------------------------------------------------------------- overrides


def _parse_override_value(text: str) -> Any:
    """Parse the right-hand side of ``--set key=value`` as a TOML value (bare words are strings)."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def apply_overrides(data: dict[str, Any], overrides: Sequence[str]) -> dict[str, Any]:
    """Apply ``section.key=value`` (dotted, any depth) overrides to raw profile data."""
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"--set {item!r}: expected section.key=value")
        path, _, raw = item.partition("=")
        keys = [k for k in path.strip().split(".") if k]
        if len(keys) < 2:
            raise ConfigError(f"--set {item!r}: expected section.key=value")
        node = data
        for k in keys[:-1]:
            node = node.setdefault(k, {})
            if not isinstance(node, dict):
                raise ConfigError(f"--set {item!r}: {k} is not a table")
        node[keys[-1]] = _parse_override_value(raw.strip())
    return data


# --------------------------------------------------------------------------- loading


def profile_names() -> list[str]:
    """Names of the profiles shipped in ``configs/`` (e.g. ``default``)."""
    root = resources.files("bipedtele.configs")
    return sorted(p.name[:-5] for p in root.iterdir() if p.name.endswith(".toml"))


def _read_profile(name_or_path: str | Path) -> tuple[str, dict[str, Any], Path | None]:
    """``(label, data, folder)``: ``folder`` is the file's folder, None for a shipped profile."""
    path = Path(name_or_path)
    folder: Path | None
    if path.suffix == ".toml" or path.is_file():
        label = str(path)
        folder = path.parent
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise ConfigError(f"{label}: cannot read config file ({exc.strerror})") from None
    else:
        name = str(name_or_path)
        res = resources.files("bipedtele.configs").joinpath(f"{name}.toml")
        if not res.is_file():
            allowed = ", ".join(profile_names())
            raise ConfigError(
                f"config {name!r}: no such file or profile; profiles: {allowed}, or a path to a .toml file"
            )
        label = f"configs/{name}.toml"
        folder = None
        text = res.read_text(encoding="utf-8")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{label}: invalid TOML: {exc}") from None
    return label, data, folder


def _resolve_path(value: Any, folder: Path | None) -> Any:
    """Return a path string with ``~`` expanded and, if relative and ``folder`` is given, under it."""
    if not isinstance(value, str) or not value:
        return value
    expanded = os.path.expanduser(value)
    if folder is None or os.path.isabs(expanded):
        return expanded
    return os.path.normpath(os.path.join(folder, expanded))


def resolve_paths(cls: type, data: Mapping[str, Any], folder: Path | None) -> dict[str, Any]:
    """Raw section ``data`` with the values of ``path=True`` fields resolved.

    Relative paths are joined to ``folder`` (the profile file's folder; None keeps them
    relative to the working folder) and ``~`` is expanded. Values of a wrong type are left
    as they are for :func:`parse_section` to reject.
    """
    try:
        hints = get_type_hints(cls)
    except Exception:  # an unresolvable annotation: parse_section will say so
        return dict(data)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    out = dict(data)
    for key, value in data.items():
        f = fields.get(key)
        if f is None:
            continue
        if f.metadata.get("path"):
            if isinstance(value, list):
                out[key] = [_resolve_path(v, folder) for v in value]
            else:
                out[key] = _resolve_path(value, folder)
            continue
        inner = dataclass_of(hints.get(key))
        if inner is None:
            continue
        if isinstance(value, Mapping):
            out[key] = resolve_paths(inner, value, folder)
        elif isinstance(value, list):
            out[key] = [resolve_paths(inner, v, folder) if isinstance(v, Mapping) else v for v in value]
    return out


REDACTED = "***"
_SECRET_NAME = re.compile(r"password|passwd|secret|token", re.IGNORECASE)
_FILE_NAME = re.compile(r"(_file|_path|_dir|_folder)$", re.IGNORECASE)


def _is_secret_name(name: str) -> bool:
    return bool(_SECRET_NAME.search(name)) and not _FILE_NAME.search(name)


def _is_set(value: Any) -> bool:
    return value is not None and value != "" and value != [] and value != {}


def _plain(value: Any, redact: bool) -> Any:
    """Return a dataclass (or container) as plain dicts/lists, secrets replaced when ``redact``."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        out: dict[str, Any] = {}
        for f in dataclasses.fields(value):
            v = getattr(value, f.name)
            secret = bool(f.metadata.get("secret")) or (not f.metadata.get("path") and _is_secret_name(f.name))
            out[f.name] = REDACTED if redact and secret and _is_set(v) else _plain(v, redact)
        return out
    if isinstance(value, Mapping):
        return {
            k: REDACTED if redact and _is_secret_name(str(k)) and _is_set(v) else _plain(v, redact)
            for k, v in value.items()
        }
    if isinstance(value, list | tuple):
        return type(value)(_plain(v, redact) for v in value)
    return value


@dataclass(frozen=True)
class Config:
    """A validated profile: one dataclass instance per section.

    Attributes
    ----------
    source : str
        File the profile came from (for messages).
    sections : dict
        Section name -> dataclass instance. Every registered section is present,
        filled with defaults where the file does not mention it.
    """

    source: str
    sections: Mapping[str, Any]

    def get(self, cls: type[T]) -> T:
        """Return the section whose class is ``cls``, typed as it (``cfg.get(LeaderConfig).operator``).

        The typed way in: each part reads the sections whose classes it owns or imports.
        :meth:`section` (by name, untyped) is for what cannot import the class: a generic
        tool, or one role reading a section another owns.

        Raises
        ------
        ConfigError
            No section of that class is registered (its part is not installed).
        """
        for value in self.sections.values():
            if type(value) is cls:
                return value
        raise ConfigError(
            f"{self.source}: no section of class {cls.__name__}; known: {', '.join(sorted(self.sections))}"
        )

    def section(self, name: str) -> Any:
        """Return the section ``name`` (a dataclass instance; untyped: prefer :meth:`get`)."""
        try:
            return self.sections[name]
        except KeyError:
            raise ConfigError(
                f"{self.source}: no section {name!r}; known: {', '.join(sorted(self.sections))}"
            ) from None

    def __getattr__(self, name: str) -> Any:
        sections = object.__getattribute__(self, "sections")
        if name in sections:
            return sections[name]
        raise AttributeError(name)

    def replace(self, name: str, **changes: Any) -> Config:
        """Return a copy with fields of one section changed (validated like the file)."""
        current = dataclasses.asdict(self.section(name))
        current.update(changes)
        new = parse_section(type(self.section(name)), current, f"{self.source}: {name}")
        return Config(self.source, {**self.sections, name: new})

    def to_dict(self, redact: bool = True) -> dict[str, Any]:
        """Plain nested dict (for recordings, ``bipedtele config`` and the cockpit).

        Parameters
        ----------
        redact : bool
            Replace secrets by ``"***"`` (the default): fields declared ``secret=True`` and
            keys named like a password, secret or token (see the module docstring). Only a
            caller that must rebuild the configuration passes False; never print, send or
            record that form.
        """
        return {k: _plain(v, redact) for k, v in self.sections.items()}


def load_config(
    profile: str | Path = "default",
    overrides: Sequence[str] = (),
    *,
    extra_sections: Mapping[str, type] | None = None,
) -> Config:
    """Load, override and validate a profile.

    Parameters
    ----------
    profile : str or Path
        A profile name shipped in ``configs/`` (``default``, ``localhost-delay``, ...)
        or a path to a TOML file.
    overrides : sequence of str
        ``section.key=value`` items, applied after the file (values in TOML syntax;
        bare words are strings).
    extra_sections : mapping, optional
        Additional section classes (for tests and embedding).

    Raises
    ------
    ConfigError
        One line naming the file, the key, the value and what is allowed.

    Notes
    -----
    Relative paths (fields declared ``path=True``) written in a profile file are resolved
    relative to that file's folder; those of shipped profiles and of ``overrides`` stay
    relative to the working folder.
    """
    label, data, folder = _read_profile(profile)
    classes = section_classes()
    if extra_sections:
        classes.update(extra_sections)
    if folder is not None:  # before the overrides: theirs stay relative to the working folder
        data = {
            name: resolve_paths(classes[name], raw, folder) if name in classes and isinstance(raw, Mapping) else raw
            for name, raw in data.items()
        }
    data = apply_overrides(data, overrides)
    unknown = sorted(set(data) - set(classes))
    if unknown:
        raise ConfigError(f"{label}: unknown section [{unknown[0]}]; known sections: {', '.join(sorted(classes))}")
    sections: dict[str, Any] = {}
    for name, cls in classes.items():
        raw = data.get(name, {})
        if not isinstance(raw, Mapping):
            raise ConfigError(f"{label}: {name} = {fmt_value(raw)}: allowed: a table [{name}]")
        sections[name] = parse_section(cls, raw, f"{label}: {name}")
    return Config(label, sections)


def resolve_section(config: Any, cls: type[T], name: str, overrides: Mapping[str, Any] | None = None) -> T:
    """Return the ``[name]`` section of type ``cls`` from whatever a device or robot was given.

    Parameters
    ----------
    config : Config, cls instance or None
        A whole profile (its ``[name]`` section is used), the section itself, or None
        (defaults).
    cls : type
        The section's dataclass.
    name : str
        The section's name, for messages.
    overrides : mapping, optional
        Fields to change; validated like the file (ranges, types, unknown keys).

    Raises
    ------
    ConfigError
        An override is unknown or out of range.
    TypeError
        ``config`` is of another type.
    """
    if config is None:
        section = cls()
    elif isinstance(config, cls):
        section = config
    elif isinstance(config, Config):
        found = config.sections.get(name)
        section = found if isinstance(found, cls) else cls()
    else:
        raise TypeError(f"config: expected {cls.__name__} or Config, got {type(config).__name__}")
    if not overrides:
        return section
    current = {f.name: getattr(section, f.name) for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(overrides) - set(current))
    if unknown:
        raise ConfigError(f"{name}.{unknown[0]}: unknown key; allowed keys: {', '.join(sorted(current))}")
    raw = {k: _as_raw(v) for k, v in {**current, **overrides}.items()}
    return parse_section(cls, raw, name)


def _as_raw(value: Any) -> Any:
    """Return a dataclass field value in the plain form a TOML file would hold."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _as_raw(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, list | tuple):
        return [_as_raw(v) for v in value]
    return value
