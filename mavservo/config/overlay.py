"""Parameters set from a ground station, kept across restarts in a file next to the config.

The YAML config stays the integrator's file: the bridge never rewrites it. What a ground station
changes (PARAM_SET) goes into ``<config stem>.params.yaml`` beside it, one ``NAME: value`` line
per parameter, and is laid over the config at every start. The overlay is written atomically
(a temporary file in the same directory, flushed to disk, then renamed over the old one), so a
power cut mid-write leaves either the old overlay or the new one, never half of each.

An overlay that no longer fits its config (the config was edited: a servo removed, a limit
narrowed) is an error at start with the overlay's FILE:LINE, like any config error; ``mavservo
params --clear CONFIG`` removes it.
"""

from __future__ import annotations

import contextlib
import math
import os
import stat
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from mavservo.config.loader import ConfigError, load_located
from mavservo.config.parameters import ParameterError, parameters_by_name, with_values
from mavservo.config.schema import Config
from mavservo.config.smallfile import SmallFileError, read_small_file
from mavservo.config.yamlsource import Problem, YamlDocument, YamlSyntaxError, parse_yaml

#: An overlay holds a few hundred short lines at most; anything far larger is not one.
MAX_OVERLAY_BYTES = 64 * 1024

_HEADER = (
    "# Parameters set from a ground station (MAVLink PARAM_SET), laid over {config} at start.\n"
    "# Written by mavservo; remove it with: mavservo params --clear {config}\n"
)


#: systemd sets this for a unit with ``StateDirectory=`` (deploy/mavservo.service): the one
#: directory such a service may write; the config itself is in a read-only credentials directory.
STATE_DIRECTORY_ENV = "STATE_DIRECTORY"


def overlay_path(config_path: str | Path) -> Path:
    """Where the overlay of ``config_path`` lives: ``sim.yaml`` -> ``sim.params.yaml``, in the
    service's state directory (``$STATE_DIRECTORY``) when there is one, else beside the config.

    Why: under the shipped unit the config is a credential (read-only): every PARAM_SET was
    answered as saved and gone after a restart (issue 32, finding 6)."""
    path = Path(config_path)
    name = f"{path.stem}.params.yaml"
    state = os.environ.get(STATE_DIRECTORY_ENV, "").split(":")[0]
    return Path(state) / name if state else path.with_name(name)


@dataclass(frozen=True)
class LoadedConfig:
    """A config with its overlay applied, and what came from the overlay."""

    config: Config
    base: Config
    overlay: dict[str, float] = field(default_factory=dict)
    warnings: list[Problem] = field(default_factory=list)
    #: the config file as parsed: the line of each key, for problems found after loading
    document: YamlDocument | None = None


def load_config_with_overlay(path: str | Path) -> LoadedConfig:
    """Load ``path`` and lay its overlay (if any) over it; ConfigError names the bad line."""
    base, warnings, document = load_located(path)
    overlay_file = overlay_path(path)
    values = read_overlay(overlay_file)
    if not values:
        return LoadedConfig(base, base, {}, warnings, document)
    config = apply_overlay(base, values, overlay_file)
    return LoadedConfig(config, base, values, warnings, document)


def read_overlay(path: Path) -> dict[str, float]:
    """The ``NAME: value`` pairs of an overlay file; {} when there is none.

    Refused with the reason (a ConfigError naming the file): a symlink to nothing (silently
    ignored before, so the values were lost unseen), a file others may write or that another
    user owns (anyone who can write it sets the aircraft's limits at the next start)."""
    if path.is_symlink() and not path.exists():
        problem = Problem(
            (),
            None,
            f"the overlay is a symlink to {os.readlink(path)}, which "
            "does not exist (remove it, or restore its target)",
        )
        raise ConfigError(str(path), [problem])
    if not path.exists():
        return {}
    _check_ownership(path)
    try:
        text = read_small_file(path, MAX_OVERLAY_BYTES).decode("utf-8")
    except (SmallFileError, UnicodeDecodeError) as exc:
        problem = Problem((), None, f"cannot read the overlay: {exc}")
        raise ConfigError(str(path), [problem]) from None
    try:
        document = parse_yaml(text)
    except YamlSyntaxError as exc:
        raise ConfigError(str(path), [Problem((), exc.line, exc.message)]) from None
    if document.problems:
        raise ConfigError(str(path), document.problems)
    data = document.data or {}
    if not isinstance(data, dict):
        raise ConfigError(str(path), [Problem((), 1, "expected NAME: value lines")])
    values: dict[str, float] = {}
    problems = []
    for name, value in data.items():
        number = isinstance(value, int | float) and not isinstance(value, bool)
        if number and isinstance(value, int) and abs(value) > 1e300:
            number = False  # a float cannot hold it: an error with its line, not a traceback
            value = f"an integer of {len(str(abs(value)))} digits"
        if not number or not math.isfinite(value):
            _, line = document.line_of((name,))
            problems.append(Problem((str(name),), line, f"expected a finite number, got {value!r}"))
            continue
        values[str(name)] = float(value)
    if problems:
        raise ConfigError(str(path), problems)
    return values


def _check_ownership(path: Path) -> None:
    """Refuse an overlay another user owns or that group or others may write."""
    info = path.stat()
    problem = None
    if info.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        problem = (
            f"the overlay is writable by {'others' if info.st_mode & stat.S_IWOTH else 'its group'}"
            f" (mode {stat.S_IMODE(info.st_mode):04o}): anyone who can write it sets the "
            f"aircraft's parameters; chmod 600 {path}"
        )
    elif hasattr(os, "geteuid") and info.st_uid not in (os.geteuid(), 0):
        problem = (
            f"the overlay is owned by user {info.st_uid}, not by this user ({os.geteuid()}) or "
            f"root; check who wrote it, then chown it or remove it"
        )
    if problem is not None:
        raise ConfigError(str(path), [Problem((), None, problem)])


def apply_overlay(base: Config, values: Mapping[str, float], path: Path) -> Config:
    """``base`` with the overlay's values; each one that does not fit is a FILE:LINE error."""
    known = parameters_by_name(base)
    problems = []
    lines = _lines_of(path)
    for name in values:
        if name not in known:
            problems.append(Problem((name,), lines.get(name), "no such parameter in this config"))
    if problems:
        raise ConfigError(str(path), problems)
    try:
        return with_values(base, values, envelope=base)
    except ParameterError as exc:
        name, reason = _culprit(base, values) or (next(iter(values)), str(exc))
        raise ConfigError(str(path), [Problem((name,), lines.get(name), reason)]) from None


def _culprit(base: Config, values: Mapping[str, float]) -> tuple[str, str] | None:
    """The first overlay value (in file order) that makes the config invalid, and why: the
    line to point at when several values are refused together."""
    applied: dict[str, float] = {}
    for name, value in values.items():
        try:
            with_values(base, {**applied, name: value}, envelope=base)
        except ParameterError as exc:
            return name, str(exc).split(": ", 1)[-1]
        applied[name] = value
    return None


def _lines_of(path: Path) -> dict[str, int]:
    """Line of each top-level key (the overlay was parsed already, so this cannot fail)."""
    with contextlib.suppress(OSError, YamlSyntaxError, UnicodeDecodeError):
        document = parse_yaml(path.read_text(encoding="utf-8"))
        if isinstance(document.data, dict):
            return {
                str(name): line
                for name in document.data
                if (line := document.line_of((name,))[1]) is not None
            }
    return {}


def write_overlay(path: Path, values: Mapping[str, float], config_name: str) -> None:
    """Replace the overlay with ``values`` atomically (0600: it is the vehicle's tuning)."""
    text = _HEADER.format(config=config_name) + "".join(
        f"{name}: {_number(value)}\n" for name, value in sorted(values.items())
    )
    write_atomic(path, text)


def write_atomic(path: Path, text: str) -> None:
    """Replace ``path`` with ``text`` atomically and durably (0600): a crash leaves the old
    file or the new one, never half of one (the overlay, the DroneCAN allocation table)."""
    fd, temporary = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as handle:
            handle.write(text)
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(temporary, 0o600)
        os.replace(temporary, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(temporary)
        raise
    _sync_directory(path.parent)


def _number(value: float) -> str:
    return str(int(value)) if value == int(value) and abs(value) < 1e15 else repr(float(value))


def _sync_directory(directory: Path) -> None:
    """Make the rename itself durable (POSIX: fsync the directory)."""
    with contextlib.suppress(OSError):
        fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def clear_overlay(config_path: str | Path) -> Path | None:
    """Remove the overlay of ``config_path``; the path removed, or None if there was none."""
    path = overlay_path(config_path)
    try:
        path.unlink()
    except FileNotFoundError:
        return None
    return path
