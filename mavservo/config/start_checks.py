"""The one verdict on a config that ``mavservo check`` prints and ``mavservo run`` starts from.

Why one place: ``check`` said "valid" for configs that ``run`` then refused at start (an slcan
bitrate python-can does not set, a SocketCAN channel that is a tty path), and, worse, for a
hardware config that had lost its ``mavlink.url``, which ``run`` drove from the built-in
simulated autopilot: it swept the real servos +-25 deg (issue 37). :func:`preflight` loads the
file (schema, cross-section checks, overlay), applies the command line's overrides, and adds
the checks that need the whole picture; ``check`` and ``run`` both call it, so they cannot
disagree.

Its errors are facts of the config (the same on every machine); its warnings are facts of this
machine (a serial device not plugged in yet, a SocketCAN interface down), which a config checked
on a laptop must not fail for.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from mavservo.config.endpoints import describe_bus
from mavservo.config.loader import ConfigError, located
from mavservo.config.overlay import LoadedConfig, load_config_with_overlay
from mavservo.config.overrides import apply_overrides
from mavservo.config.schema import Config
from mavservo.config.semantic import Finding
from mavservo.config.urls import SIM
from mavservo.config.yamlsource import Problem, format_path
from mavservo.errors import MavservoError
from mavservo.transport import bus_problems, device_problems, reaches_hardware
from mavservo.transport import serial_device_problem as _serial_device_problem

#: What to write instead of the simulated autopilot, in every message that refuses it.
AUTOPILOT_LINK_HINT = (
    "set mavlink.url to the autopilot's link: `url: /dev/serial0` with `baud: 921600` (a "
    "Raspberry Pi's UART wired to the autopilot's TELEM2), `url: udpin:0.0.0.0:14550` (from a "
    "MAVLink router or a network), or `--mavlink URL` on the command line; or make the bus "
    "simulated (`channel: sim`)"
)


class SimulatedAutopilotError(MavservoError):
    """The built-in simulated autopilot was asked to drive a bus that reaches hardware."""


def url_was_set(config: Config) -> bool:
    """Whether the file (or ``--mavlink``) set ``mavlink.url``, rather than its default."""
    return "mavlink" in config.model_fields_set and "url" in config.mavlink.model_fields_set


def simulated_autopilot_findings(config: Config, *, port: str | None = None) -> list[Finding]:
    """The built-in simulated autopilot (``mavlink.url: sim``, also the default) only ever
    drives simulated buses: with any bus that reaches hardware, one finding, on the
    ``mavlink.url`` line when the file wrote ``sim``, else on the first real bus's channel.
    ``port``: the ``--port`` that replaced the first bus's channel, named in the message."""
    if config.mavlink.url != SIM:
        return []
    real = [
        (index, bus)
        for index, bus in enumerate(config.can.buses)
        if reaches_hardware(bus.interface, bus.channel)
    ]
    if not real:
        return []
    buses = "; ".join(
        f"{bus.name} ({describe_bus(bus)}"
        + (f", from --port {port}" if index == 0 and port is not None else "")
        + ")"
        for index, bus in real
    )
    first = real[0][0]
    loc: tuple[str | int, ...]
    if url_was_set(config):
        why, loc = "mavlink.url is 'sim'", ("mavlink", "url")
    else:
        why, loc = "mavlink.url is not set", ("can", "buses", first, "channel")
    message = (
        f"{why}, so the built-in simulated autopilot would move the real servos of bus "
        f"{buses}; it only drives simulated buses, so nothing starts: {AUTOPILOT_LINK_HINT}"
    )
    return [(loc, message)]


def start_findings(config: Config, *, port: str | None = None) -> list[Finding]:
    """Every error :func:`preflight` adds to the loader's: the simulated autopilot on a real
    bus, and each bus's channel and bitrate against its interface's rules."""
    findings = simulated_autopilot_findings(config, port=port)
    for index, bus in enumerate(config.can.buses):
        origin = f"--port {port}: " if index == 0 and port is not None else ""
        findings += [
            (("can", "buses", index, problem.key), origin + problem.message)
            for problem in bus_problems(bus.interface, bus.channel, bus.bitrate)
        ]
    return findings


def machine_findings(config: Config) -> list[Finding]:
    """Warnings about this machine: devices named by the config that are not there (yet)."""
    findings: list[Finding] = []
    url = config.mavlink.url
    if url.startswith("/"):
        device = url.rpartition(",")[0] if "," in url else url  # pymavlink's DEVICE,BAUD
        problem = _serial_device_problem(device)
        if problem is not None:
            findings.append((("mavlink", "url"), f"the autopilot link: {problem}"))
    for index, bus in enumerate(config.can.buses):
        findings += [
            (("can", "buses", index, problem.key), f"bus {bus.name}: {problem.message}")
            for problem in device_problems(bus.interface, bus.channel, bus.bitrate)
        ]
    return findings


@dataclass(frozen=True)
class Preflight:
    """A config ``run`` may start and ``check`` calls valid, with where each of its keys is."""

    path: Path
    loaded: LoadedConfig
    #: the config in force: the file, its overlay, then the command line's overrides
    config: Config
    warnings: list[Problem]
    #: the command line's ``--mavlink`` and ``--port``, which replace what the file says
    overrides: dict[tuple[str | int, ...], str] = field(default_factory=dict)

    def line_of(self, loc: Sequence[str | int]) -> int | None:
        """The line of key ``loc`` in the file (None when it is not written there)."""
        document = self.loaded.document
        return None if document is None else document.line_of(loc)[1]

    def place(self, loc: Sequence[str | int]) -> str:
        """``FILE:LINE: key`` of ``loc``, for a message about it found after loading; the
        command-line option instead when one replaced the key (a failing ``--mavlink URL`` is
        not the file's line)."""
        option = self.overrides.get(tuple(loc))
        if option is not None:
            return f"{option}, replacing {format_path(loc)}"
        line = self.line_of(loc)
        where = f"{self.path}:{line}" if line is not None else str(self.path)
        return f"{where}: {format_path(loc)}"


def preflight(
    path: str | Path, *, mavlink: str | None = None, port: str | None = None
) -> Preflight:
    """Load ``path`` for a run (``mavlink``/``port``: the ``--mavlink``/``--port`` overrides).

    Raises :class:`ConfigError` (FILE:LINE per problem) or
    :class:`~mavservo.config.overrides.OverrideError` (naming the option); touches no device
    (whether one exists is only looked at, for the warnings)."""
    path = Path(path)
    loaded = load_config_with_overlay(path)
    config = apply_overrides(loaded.config, mavlink, port)
    errors = start_findings(config, port=port)
    if errors:
        raise ConfigError(str(path), located(errors, loaded.document))
    warnings = [*loaded.warnings, *located(machine_findings(config), loaded.document)]
    overrides: dict[tuple[str | int, ...], str] = {}
    if mavlink is not None:
        overrides[("mavlink", "url")] = f"--mavlink {mavlink}"
    if port is not None:
        overrides[("can", "buses", 0, "channel")] = f"--port {port}"
    return Preflight(path, loaded, config, warnings, overrides)


def refuse_simulated_autopilot_on_hardware(config: Config) -> None:
    """Raise :class:`SimulatedAutopilotError` for a config whose simulated autopilot would drive
    a real bus: the bridge's own guard, for a config that did not come through
    :func:`preflight` (a program or a test that builds its :class:`Config` itself)."""
    for _loc, message in simulated_autopilot_findings(config):
        raise SimulatedAutopilotError(message)
