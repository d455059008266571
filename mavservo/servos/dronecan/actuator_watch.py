"""Which commanded DroneCAN actuators never report, or stop reporting, while their node lives.

A DroneCAN servo is online on its node's NodeStatus, but its position comes from the actuator
``Status`` of its own actuator id. A node that ignores the command (a command type it does not
act on, an actuator id it does not have) stays online and shows no position; one whose actuator
stops reporting shows a position as old as its last Status, as if current. Telling the crew is
one job with its own state (when each servo was first and last commanded, who was warned),
fed by :class:`.node.BridgeNode` as it packs commands and ticks; it reads only a servo's
timestamps and options (:class:`WatchedServo`), so it is tested on plain objects. Pure: no
clock, no I/O; times are handed in.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from typing import Protocol

from .notices import Notices

SILENT_ACTUATOR_S = 3.0
"""A servo whose node is alive and which is commanded, but which has sent no report of its
own actuator for this long, is warned about once (its commands are likely ignored)."""


class WatchedServoOptions(Protocol):
    """What the watch reads of a servo's options: which actuator, which firmware, which
    command type (said in the warnings)."""

    @property
    def actuator_id(self) -> int: ...

    @property
    def firmware(self) -> str: ...

    @property
    def command(self) -> str: ...


class WatchedServo(Protocol):
    """What the watch reads of a DroneCAN servo: when its node and its actuator were heard."""

    @property
    def can_id(self) -> int: ...

    @property
    def node_heard_at(self) -> float | None: ...

    @property
    def node_last_heard(self) -> float | None: ...

    @property
    def actuator_reported_at(self) -> float | None: ...

    @property
    def options(self) -> WatchedServoOptions: ...


class ActuatorWatch:
    """Warns once per servo that never reports while commanded, and once per episode for one
    that stopped reporting while commanded (its next report ends the episode)."""

    def __init__(
        self, servos: Sequence[WatchedServo], counters: Counter[str], notices: Notices
    ) -> None:
        self.servos = servos
        self._counters = counters
        self._notices = notices
        self._commanded_since: dict[int, float | None] = {}
        """Servo index -> when the watch first saw it commanded (None: in the slot just packed,
        the time comes with the next :meth:`check`)."""
        self._silent_warned: set[int] = set()
        self._packed: set[int] = set()
        """Servo indexes commanded in the slots packed since the last :meth:`check`."""
        self._last_commanded: dict[int, float] = {}
        """Servo index -> when a command for it was last packed (set in :meth:`check`)."""
        self._stopped_warned: set[int] = set()
        """Servos warned about for a Status that stopped (again once one comes)."""

    def commanded(self, index: int, release: bool) -> None:
        """A command for servo ``index`` was packed (``release``: one that lets go of the servo,
        which then rightly may stop reporting)."""
        self._commanded_since.setdefault(index, None)
        if not release:
            self._packed.add(index)

    def check(self, now: float) -> None:
        """Warn once per servo whose node is alive and which is commanded but never reports
        its actuator: the node ignores the command (a command type it does not act on, an
        actuator id it does not have); and once per episode for one that did report and
        stopped while its node goes on (:meth:`_check_stopped`)."""
        for index in self._packed:
            self._last_commanded[index] = now
        self._packed.clear()
        self._check_stopped(now)
        for index, since in list(self._commanded_since.items()):
            if since is None:
                self._commanded_since[index] = now
                continue
            servo = self.servos[index]
            if index in self._silent_warned or servo.actuator_reported_at is not None:
                continue
            alive = servo.node_heard_at
            if alive is None or now - max(since, alive) < SILENT_ACTUATOR_S:
                continue
            self._silent_warned.add(index)
            self._counters["silent_actuators"] += 1
            options = servo.options
            if options.firmware == "ardupilot":
                # AP_Periph sends actuator Status only as a SITL build (rc_out.cpp,
                # sim_update_actuator) or with its actuator telemetry set up (actuator_telem.cpp,
                # no position): a real board that drives its outputs is silent here
                self._notices.add(
                    f"DroneCAN node {servo.can_id} is alive but never reports Status for "
                    f"actuator {options.actuator_id}: expected of a real AP_Periph board (it "
                    "sends actuator Status only as a SITL build, or with its ACT telemetry set "
                    "up): the position is not known, the servo is online on NodeStatus alone; "
                    "if the node is a SITL build, check the actuator id"
                )
                continue
            self._notices.add(
                f"DroneCAN node {servo.can_id} is alive but never reports Status for actuator "
                f"{options.actuator_id}: commands ignored? check the command type (command: "
                f"{options.command}; ArduPilot peripherals act on unitless and pwm only) and "
                "the actuator id"
            )

    def _check_stopped(self, now: float) -> None:
        """An actuator that reported and has sent nothing for :data:`SILENT_ACTUATOR_S` while
        it is commanded and its node's NodeStatus goes on: the servo stays online on that
        NodeStatus, its last position shown as if current, so the crew is told (once per
        episode; a report ends it). A released servo is not commanded: an ArduPilot SITL node
        stops its Status then, as it should."""
        for index, servo in enumerate(self.servos):
            reported = servo.actuator_reported_at
            if reported is None:
                continue
            if now - reported < SILENT_ACTUATOR_S:
                self._stopped_warned.discard(index)
                continue
            commanded = self._last_commanded.get(index)
            node = servo.node_last_heard
            if (
                index in self._stopped_warned
                or commanded is None
                or now - commanded > 1.0
                or node is None
                or now - node > SILENT_ACTUATOR_S
            ):
                continue
            self._stopped_warned.add(index)
            self._counters["stopped_actuators"] += 1
            self._notices.add(
                f"DroneCAN node {servo.can_id} is alive but actuator "
                f"{servo.options.actuator_id} has sent no Status for {now - reported:.0f} s "
                "while commanded: its position shown is that old (the servo stays online on the "
                "node's NodeStatus); a failed actuator or a broken output?"
            )
