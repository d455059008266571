"""Command-line overrides (``--mavlink``, ``--port``) applied to a validated config.

Two things a plain ``model_dump`` / ``model_validate`` round trip gets wrong: a bad option would
be reported as ``mavlink.url`` with no word of the option that set it, and every key would count
as "set", so :func:`~mavservo.config.endpoints.endpoint_lines` could no longer say that a
simulation was chosen because the file left a key out. Only the keys the file set (plus the
overrides) are carried over.
"""

from __future__ import annotations

from typing import Any

from pydantic import ValidationError

from mavservo.config.schema import Config
from mavservo.config.urls import url_problem
from mavservo.errors import MavservoError


class OverrideError(MavservoError, ValueError):
    """A command-line override that cannot be used; the message names the option."""


def apply_overrides(config: Config, mavlink: str | None = None, port: str | None = None) -> Config:
    """``config`` with ``mavlink.url`` and/or the first bus's channel replaced.

    Raises :class:`OverrideError` naming ``--mavlink`` or ``--port``.
    """
    if mavlink is None and port is None:
        return config
    if mavlink is not None:
        problem = url_problem(mavlink)
        if problem is not None:
            raise OverrideError(f"--mavlink {mavlink}: {problem}")
    if port is not None and not port.strip():
        raise OverrideError("--port: expected a serial device such as /dev/ttyUSB0, got ''")
    data: dict[str, Any] = config.model_dump(mode="python", exclude_unset=True)
    if mavlink is not None:
        data.setdefault("mavlink", {})["url"] = mavlink
    if port is not None:
        buses = data.setdefault("can", {}).setdefault("buses", [{}])
        buses[0]["channel"] = port
    try:
        return Config.model_validate(data)
    except ValidationError as exc:
        options = " ".join(
            f"{flag} {value}" for flag, value in (("--mavlink", mavlink), ("--port", port)) if value
        )
        reasons = "; ".join(error["msg"] for error in exc.errors(include_url=False))
        raise OverrideError(f"{options}: {reasons}") from None
