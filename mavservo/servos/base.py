"""The common vocabulary of every servo profile: state, faults, and the profile contract.

A profile is the only place that knows what a servo's CAN payload means, and it describes itself
(ids, options, lifecycle frames, telemetry shape, simulated device), so nothing above it (schema,
``check``, the bus-load budget, the scheduler, the simulator) keeps a copy of its facts. The
contract is written down in ``docs/profiles.md``. Everything above deals in :class:`ServoState`
and :class:`Fault`. Profiles are pure: no I/O, no threads, no clock; times are handed in.
"""

from __future__ import annotations

import enum
import math
from abc import ABC, abstractmethod
from collections.abc import Hashable, Sequence
from dataclasses import dataclass, replace
from typing import Any, ClassVar, Literal, Protocol, runtime_checkable

import can
from pydantic import BaseModel, ConfigDict

UNKNOWN = math.nan
"""Value of a field that no reply has reported yet (NaN, so it never passes for a reading)."""


class Fault(enum.Flag):
    """Named fault conditions, one vocabulary for all protocols.

    Raw error bits and error codes differ per servo family; each profile maps its own encoding
    onto these members so consumers (STATUSTEXT, gimbal failure flags) never see raw integers.
    ``NO_REPLY`` is never set by a servo: the scheduler raises it when a servo goes silent.
    """

    STALL = enum.auto()
    LOW_VOLTAGE = enum.auto()
    OVER_VOLTAGE = enum.auto()
    OVER_CURRENT = enum.auto()
    POWER = enum.auto()
    OVERSPEED = enum.auto()
    OVER_TEMPERATURE = enum.auto()
    ENCODER = enum.auto()
    PHASE_IMBALANCE = enum.auto()
    OTHER = enum.auto()
    """An error bit or code the profile does not know by name (never hidden as "no fault")."""
    NO_REPLY = enum.auto()
    # Members below were added with the Robstride and ODrive profiles; new members go at the
    # end so the bit values published in ``s<n>_flt`` never move.
    UNCALIBRATED = enum.auto()
    """The motor's encoder or motor calibration is missing (Robstride, ODrive)."""
    DRIVER = enum.auto()
    """The gate-driver chip or power stage hardware reports a fault."""
    COMMUNICATION_LOST = enum.auto()
    """The servo's own communication timeout or watchdog expired and it stopped by itself."""


NO_FAULT = Fault(0)


@dataclass(frozen=True)
class ServoState:
    """One servo's state in engineering units, as last reported.

    Fields a reply did not carry keep the last reported value (profiles merge partial replies),
    or :data:`UNKNOWN` (NaN) if nothing has reported them yet. ``timestamp`` is the receive time
    of the reply that produced this state, in whatever clock the caller passed in.
    """

    position_deg: float
    velocity_dps: float
    current_a: float
    temperature_c: float
    faults: Fault
    timestamp: float
    voltage_v: float | None = None

    @classmethod
    def unknown(cls, timestamp: float = 0.0) -> ServoState:
        """A state with nothing known yet: the starting point of a profile's merge."""
        return cls(UNKNOWN, UNKNOWN, UNKNOWN, UNKNOWN, NO_FAULT, timestamp)

    def with_faults(self, faults: Fault) -> ServoState:
        """Copy with a different fault set (e.g. the scheduler adding ``Fault.NO_REPLY``)."""
        return replace(self, faults=faults)


@dataclass(frozen=True)
class FrameId:
    """One CAN identifier a servo is sent or sends, for collision checks (``docs/profiles.md``).

    ``id_mask`` keeps the id bits that identify the frame (-1: all of them); ``first_byte`` is
    ``(value, mask)`` on ``data[0]`` for families that name the servo in the payload; ``shared``
    marks a broadcast every servo of the family on the bus shares (not a collision between them).
    """

    arbitration_id: int
    extended: bool
    direction: Literal["to_servo", "from_servo"]
    purpose: str
    id_mask: int = -1
    first_byte: tuple[int, int] | None = None
    shared: bool = False

    def matches(self, msg: can.Message) -> bool:
        """True if ``msg`` is a frame this identifier describes."""
        if bool(msg.is_extended_id) != self.extended:
            return False
        mask = self.id_mask & (0x1FFFFFFF if self.extended else 0x7FF)
        if (msg.arbitration_id ^ self.arbitration_id) & mask:
            return False
        if self.first_byte is not None:
            value, byte_mask = self.first_byte
            if not msg.data or (msg.data[0] ^ value) & byte_mask:
                return False
        return True

    def overlaps(self, other: FrameId) -> bool:
        """True when some frame could be taken for both (same format, agreeing on every id bit
        and first-byte bit both keep)."""
        if self.extended != other.extended:
            return False
        mask = self.id_mask & other.id_mask & (0x1FFFFFFF if self.extended else 0x7FF)
        if (self.arbitration_id ^ other.arbitration_id) & mask:
            return False
        if self.first_byte is not None and other.first_byte is not None:
            (a, a_mask), (b, b_mask) = self.first_byte, other.first_byte
            if (a ^ b) & a_mask & b_mask:
                return False
        return True

    def describe(self) -> str:
        """``0x141 (std)`` or ``0x2901 (ext)``, plus the byte filter, for messages."""
        text = f"0x{self.arbitration_id:X} ({'ext' if self.extended else 'std'})"
        if self.id_mask != -1:
            text += f" mask 0x{self.id_mask & 0x1FFFFFFF:X}"
        if self.first_byte is not None:
            text += f" data[0]=0x{self.first_byte[0]:02X}/0x{self.first_byte[1]:02X}"
        return text


class ProfileOptions(BaseModel):
    """Base of every profile's per-servo ``options:`` model.

    Unknown keys are refused (a typo must not leave a servo on a default), numbers are strict
    (YAML ``yes`` is not 1) and finite, instances are immutable. Every field needs a safe default,
    its unit in its name or description, and bounds (``Field(ge=..., le=...)``).
    """

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)


class SimMotor(Protocol):
    """The simulated motor a :class:`SimDevice` drives (``mavservo.sim.servo.SimServo``)."""

    can_id: int
    position_deg: float
    velocity_dps: float
    temperature_c: float
    enabled: bool

    @property
    def voltage_v(self) -> float: ...

    @property
    def active_faults(self) -> Fault: ...

    def measured_current_a(self) -> float: ...

    def command_position(
        self,
        angle_deg: float,
        speed_dps: float | None,
        now: float,
        accel_dps2: float | None = None,
    ) -> None: ...

    def enable(self, now: float) -> None: ...

    def disable(self, now: float) -> None: ...

    def set_zero(self, now: float) -> None: ...


class SimDevice(Protocol):
    """The device side of a profile: what the real servo answers to the frames it accepts."""

    pushes: bool
    """True: :meth:`status` is called at the servo's telemetry rate."""

    def accepts(self, msg: can.Message) -> bool: ...

    def handle(self, msg: can.Message, now: float) -> list[can.Message]: ...

    def status(self, now: float) -> list[can.Message]: ...

    def tick(self, now: float) -> None: ...


class BusNodeError(ValueError):
    """A bus node refuses its servos: ``servo`` is the index (in the list the node was given)
    of the servo to change, None for the node's own options; ``key`` the option at fault."""

    def __init__(self, message: str, servo: int | None, key: str) -> None:
        super().__init__(message)
        self.servo = servo
        self.key = key


NodeHealth = Literal["ok", "warning", "error"]
"""The bridge's own state as a bus node reports it: every servo of the bus online, some
offline, all offline."""


class BusNode(Protocol):
    """What the servos of one family on one bus share, for families that need it (DroneCAN:
    the bridge's own node, one broadcast command for every servo, a heartbeat).

    Built by the profile class (:meth:`ServoProfile.bus_node`), owned by the scheduler, which
    stays the only writer: it asks the node for frames and sends them. Pure, like a profile:
    times are handed in.
    """

    def pack(
        self, commands: Sequence[can.Message], in_failsafe: bool | None = False
    ) -> list[can.Message]:
        """The frames that carry these servos' command frames (one slot's; a release frame is
        one too) together; ``in_failsafe``: every setpoint among them is a failsafe one (None:
        no setpoint among them, releases only)."""
        ...

    def due(self, now: float, health: NodeHealth) -> list[can.Message]:
        """The node's own frames due by ``now`` (heartbeat, answers to requests it received)."""
        ...

    def next_due(self) -> float:
        """When :meth:`due` has something next (the scheduler wakes for it)."""
        ...

    def receive(self, msg: can.Message, now: float) -> bool:
        """A received frame; True when it left something to send at once (an answer)."""
        ...

    def take_notices(self) -> list[str]:
        """Things worth telling the operator once (another master on the bus), then forgotten."""
        ...

    def describe(self, servo_names: Sequence[str]) -> list[str]:
        """Lines for ``mavservo check``: what the node is and when its bus may be shared."""
        ...

    def persistent_state(self) -> tuple[int, dict[str, Any]] | None:
        """``(version, node options to restore)`` worth keeping across restarts (DroneCAN: the
        allocation table), saved by the bridge whenever the version changes; None: nothing."""
        ...

    def bus_frames_per_second(
        self, servo_count: int, command_hz: float
    ) -> list[tuple[float, bool, int]]:
        """``(frames per second, extended, dlc)`` the node puts on the bus, for the budget: its
        heartbeat, and the commands of ``servo_count`` servos packed together (the scheduler
        does not count their per-servo command frames besides)."""
        ...


def clamp_int(value: float, low: int, high: int) -> int:
    """``value`` as an int saturated to a field's range (simulated devices fill fields with it)."""
    return max(low, min(high, int(value)))


class ServoProfile(ABC):
    """Translate setpoints into CAN frames and CAN frames into :class:`ServoState`.

    One instance per physical servo (constructed with its ``can_id``). An instance remembers the
    last decoded state only so that replies carrying a subset of the fields (e.g. a fault report
    without a position) can be merged into a complete state; that memory is the only state.
    """

    name: str = ""
    """Short name used in YAML (``rmd-x``, ``lk``, ``cubemars-ak``), lower case, unique."""
    Options: ClassVar[type[ProfileOptions]] = ProfileOptions
    """The per-servo ``options:`` model (no options: the empty base)."""
    telemetry: ClassVar[Literal["polled", "pushed"]] = "polled"
    """Polled: the scheduler sends :meth:`telemetry_requests`; pushed: the servo reports on its
    own at its ``telemetry_hz``, and is offline after silence whether commanded or not."""
    resolution_deg: float = 1.0
    """Finest position step the servo's regular telemetry reply can express."""
    replies_per_command: int = 1
    """Replies a position command provokes (used for bus-load budgeting)."""
    replies_per_request: int = 1
    """Replies each telemetry request provokes."""
    replies_per_lifecycle: int = 0
    """Replies each start-up, release or shutdown frame provokes (the scheduler expects them,
    so an answer is neither a late reply nor a bad one)."""
    min_id: int = 1
    max_id: int = 32
    min_angle_deg: float = -math.inf
    max_angle_deg: float = math.inf
    max_speed_dps: float = math.inf

    def __init__(
        self, can_id: int, options: ProfileOptions | None = None, **overrides: Any
    ) -> None:
        """``options``: an instance of :attr:`Options` (None: every default); ``overrides``:
        option fields by keyword (validated by :attr:`Options`), for tests and scripts."""
        if not self.min_id <= can_id <= self.max_id:
            raise ValueError(f"{self.name}: servo id {can_id} outside {self.min_id}..{self.max_id}")
        self.can_id = can_id
        self.options = self._options(options, overrides)
        self.last_state: ServoState | None = None
        """The last decoded state, or None before the first reply."""

    @classmethod
    def _options(cls, options: ProfileOptions | None, overrides: dict[str, Any]) -> Any:
        """The validated options: ``options`` (or the defaults) with ``overrides`` applied."""
        if options is not None and not isinstance(options, cls.Options):
            raise TypeError(f"{cls.name}: options must be {cls.Options.__name__}")
        if not overrides:
            return options if options is not None else cls.Options()
        base = options.model_dump() if options is not None else {}
        return cls.Options.model_validate({**base, **overrides})

    @abstractmethod
    def identifiers(self) -> tuple[FrameId, ...]:
        """Every frame the bridge sends to this servo and the servo sends (collision checks)."""

    def startup_frames(self) -> list[can.Message]:
        """Sent before the first command and again when :meth:`needs_startup` turns true:
        enable, mode, the servo's own communication-loss timeout. Default: none."""
        return []

    def needs_startup(self) -> bool:
        """True after a decoded reply says the servo is disabled or timed out by itself."""
        return False

    telemetry_hz: float | None = None
    """The servo's configured ``telemetry_hz`` (None: not configured, e.g. a bare instance),
    set by the config when it builds the profile: a pushed family that programs its servo's
    own report period at start-up (Robstride's EPScan_time) takes the rate from here."""

    def shutdown_frames(self) -> list[can.Message]:
        """Sent once when the bridge stops, after the failsafe action. Default: none."""
        return []

    STOP_BEHAVIOUR: ClassVar[str] = "holds its last target (no timeout of its own)"
    """What a servo of the family does by itself when the bridge's frames stop (the bridge
    stopped, the bus or the adapter gone), as its maker documents it: ``check``'s failsafe plan
    and the stop summary print it, so "hold" is never promised for a servo that goes limp."""

    def stop_behaviour(self) -> str:
        """:attr:`STOP_BEHAVIOUR`, with the servo's own timeout when one is configured
        (:class:`CommTimeout`); a family whose behaviour depends on its options overrides
        this (DroneCAN: the node's firmware)."""
        timeout = comm_timeout_of(self)
        if timeout is None:
            return self.STOP_BEHAVIOUR
        return (
            f"{self.STOP_BEHAVIOUR}; its own timeout stops it {timeout * 1000:g} ms after the "
            "last frame"
        )

    @classmethod
    @abstractmethod
    def sim_device(cls, motor: SimMotor, can_id: int, options: ProfileOptions) -> SimDevice:
        """The device side for the built-in simulation and ``mavservo sim``."""

    def _merge(
        self,
        timestamp: float,
        *,
        position_deg: float | None = None,
        velocity_dps: float | None = None,
        current_a: float | None = None,
        temperature_c: float | None = None,
        faults: Fault | None = None,
        voltage_v: float | None = None,
    ) -> ServoState:
        """Fold a partial reply into the last known state and remember the result.

        A field the reply did not carry (None) keeps its last known value.
        """
        base = self.last_state or ServoState.unknown()
        self.last_state = ServoState(
            position_deg=base.position_deg if position_deg is None else position_deg,
            velocity_dps=base.velocity_dps if velocity_dps is None else velocity_dps,
            current_a=base.current_a if current_a is None else current_a,
            temperature_c=base.temperature_c if temperature_c is None else temperature_c,
            faults=base.faults if faults is None else faults,
            timestamp=timestamp,
            voltage_v=base.voltage_v if voltage_v is None else voltage_v,
        )
        return self.last_state

    @abstractmethod
    def position_command(self, angle_deg: float, max_speed_dps: float | None = None) -> can.Message:
        """Frame that moves the servo to ``angle_deg``, at most ``max_speed_dps`` if supported."""

    @abstractmethod
    def telemetry_requests(self) -> list[can.Message]:
        """Frames the next telemetry poll sends; empty for servos that push their status.

        A query: asking (the bus-load budget, the scheduler's start-up checks) changes nothing.
        The scheduler reports a poll that went out with :meth:`poll_sent`.
        """

    def poll_sent(self) -> None:
        """The poll :meth:`telemetry_requests` described went out: move on to the next one.

        Profiles that interleave requests of several kinds (RMD-X: a fault read every Nth poll)
        count here, where polls are sent, so that building a budget consumes none. The default
        has nothing to count.
        """
        return None

    @abstractmethod
    def is_reply(self, msg: can.Message) -> bool:
        """True if ``msg`` was sent by this servo (by ID and frame format)."""

    @abstractmethod
    def decode(self, msg: can.Message, timestamp: float) -> ServoState | None:
        """State after reply ``msg`` received at ``timestamp``; None if not this servo's reply."""

    def exchange_key(self, msg: can.Message) -> Hashable | None:
        """What a request and the reply that answers it have in common, or None.

        The scheduler matches a reply only to an outstanding request with the same key, so a
        lost reply is not credited to the next request of another kind. None (the default)
        means this protocol's replies do not say what they answer.
        """
        return None

    def _check_angle(self, angle_deg: float) -> None:
        """Reject non-finite or unrepresentable angles: silently clamping one would move the
        servo somewhere nobody asked for. Limits are the mapping layer's job, not ours."""
        if not math.isfinite(angle_deg):
            raise ValueError(f"{self.name}: angle must be finite, got {angle_deg!r}")
        if not self.min_angle_deg <= angle_deg <= self.max_angle_deg:
            raise ValueError(
                f"{self.name}: angle {angle_deg} deg outside the protocol range "
                f"{self.min_angle_deg}..{self.max_angle_deg}"
            )

    def _speed_limit(self, max_speed_dps: float | None, default: float) -> float:
        """Validate a speed limit and saturate it to what the field can carry.

        Saturation is safe here (a servo cannot go faster than its own limit anyway), whereas a
        negative or NaN speed is a caller bug and raises.
        """
        speed = default if max_speed_dps is None else max_speed_dps
        if math.isnan(speed) or speed < 0:
            raise ValueError(f"{self.name}: speed limit must be >= 0, got {speed!r}")
        return min(speed, self.max_speed_dps)


# ---------------------------------------------------------------------------- capabilities
# What only some families do, each a runtime-checkable Protocol that a profile (or, for a bus
# node, a profile class) meets by defining its members; callers ask with isinstance (or the
# helpers below), never with getattr, and a profile without the capability is not asked.


@runtime_checkable
class Releasing(Protocol):
    """A family that can switch its motor off (torque free): ``failsafe: release``."""

    def release_frames(self) -> list[can.Message]:
        """Motor off, as the frames that do it. Empty: this servo's options cannot release."""
        ...


@runtime_checkable
class CommTimeout(Protocol):
    """A servo with a communication timeout or watchdog of its own."""

    def comm_timeout_s(self) -> float | None:
        """The servo's own communication timeout or watchdog as configured (seconds): it stops
        or disarms by itself after this long without a frame from the bridge. ``check`` warns
        when the keep-alive is not shorter. None: not configured."""
        ...


@runtime_checkable
class SplitStartup(Protocol):
    """A start-up that must be split in two so that CAN arbitration cannot reorder it."""

    def startup_continues(self) -> bool:
        """True when the last start-up was a first step whose next step (asked for with
        ``needs_startup``) may go at the next command slot instead of after the scheduler's
        retry interval (Robstride: the enable after the mode write): it then costs one command
        slot, not a second of commands the motor ignores. The scheduler allows one such early
        step per start-up."""
        ...


@runtime_checkable
class UnsolicitedFrames(Protocol):
    """A servo that sends frames on its own besides its telemetry (ODrive's heartbeat)."""

    def unsolicited_hz(self) -> float:
        """Frames per second it sends unasked, which the bus-load budget counts."""
        ...


@runtime_checkable
class BusNodeFamily(Protocol):
    """A family whose servos on one bus share a node (DroneCAN): met by the profile class.

    ``NodeOptions`` is the model of the bus-level ``node:`` options; :meth:`bus_node` builds
    the node the scheduler owns; :meth:`link_sim_devices` lets the simulated devices of one
    bus meet (a DroneCAN node with several actuators: one node, one heartbeat)."""

    NodeOptions: type[ProfileOptions]

    def bus_node(
        self,
        profiles: Sequence[ServoProfile],
        options: ProfileOptions | None,
        software_version: tuple[int, int],
        start: float,
        unique_id: bytes = ...,
    ) -> BusNode:
        """The node this family's servos on one bus share (``profiles``: those servos).
        ``unique_id``: the node's identity on the bus, stable for this machine and bus."""
        ...

    def link_sim_devices(self, devices: Sequence[SimDevice]) -> None:
        """Let the simulated devices of this family on one bus meet."""
        ...


@runtime_checkable
class CountingNode(Protocol):
    """A :class:`BusNode` that counts what it saw of the bus (hostile traffic included)."""

    def stats(self) -> dict[str, int]:
        """Counts for the run summary and ``metrics.json``."""
        ...


@runtime_checkable
class ActuatorOptions(Protocol):
    """The options of a servo that is one actuator of a node (DroneCAN's ``actuator_id``)."""

    actuator_id: int


@runtime_checkable
class Advising(Protocol):
    """A family that can tell when its servo answers in a form it is not configured for."""

    def diagnose(self, msg: can.Message) -> str | None:
        """Why ``msg``, a frame no servo of the bus claims, looks like this servo's in a form
        it is not configured for (another protocol, another host id), as advice naming the
        option to change; None when it does not. Called for unclaimed frames until the first
        advice; the scheduler logs it and announces it once."""
        ...

    def silence_hint(self) -> str | None:
        """The likely causes to name when this servo goes offline without ever having
        answered (wrong protocol, id, bitrate); None: nothing to add."""
        ...


@runtime_checkable
class ConfigWarnings(Protocol):
    """A family with settings that load but will likely not do what the user means."""

    def config_warnings(self) -> list[str]:
        """Such settings of this servo (a numbering convention of the servo's firmware), for
        ``check``'s warnings."""
        ...


@runtime_checkable
class NodeReports(Protocol):
    """A pushing family whose reports come from a node (DroneCAN): the node's own heartbeat
    says it is alive, and a report may take several frames."""

    heartbeat_period_s: ClassVar[float]
    """The node's heartbeat period (DroneCAN NodeStatus, 1 s): the scheduler's silence limit
    is ``offline_after_missed`` heartbeats, whatever the status rate."""
    frames_per_push: ClassVar[int]
    """CAN frames one status push takes (a multi-frame transfer: more than one)."""

    def is_liveness_only(self, msg: can.Message) -> bool:
        """True for a report that only says the servo is alive (a NodeStatus, which any node
        can send with the servo's id): it keeps the servo online and its faults current, but
        answers no command, so it closes no round trip and adds no latency sample."""
        ...

    def completes_report(self, msg: can.Message) -> bool:
        """False for a frame of this servo that only starts or continues a multi-frame report:
        the scheduler logs it but counts neither a reply nor a new state until the frame that
        completes it."""
        ...


def release_frames_of(profile: ServoProfile) -> list[can.Message]:
    """The profile's release frames, or none for a family that cannot release."""
    return profile.release_frames() if isinstance(profile, Releasing) else []


def comm_timeout_of(profile: ServoProfile) -> float | None:
    """The servo's own communication timeout in seconds, or None (none declared)."""
    return profile.comm_timeout_s() if isinstance(profile, CommTimeout) else None


def unsolicited_hz_of(profile: ServoProfile) -> float:
    """Frames per second the servo sends unasked besides its telemetry (0: none)."""
    return profile.unsolicited_hz() if isinstance(profile, UnsolicitedFrames) else 0.0


def node_reports_of(profile: ServoProfile) -> NodeReports | None:
    """The profile as :class:`NodeReports`, or None: every frame is a whole report that
    answers, and silence is counted in status periods."""
    return profile if isinstance(profile, NodeReports) else None


def node_family(cls: type[ServoProfile]) -> BusNodeFamily | None:
    """The profile class as a :class:`BusNodeFamily`, or None: its servos stand alone."""
    return cls if isinstance(cls, BusNodeFamily) else None
