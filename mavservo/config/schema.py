"""The shape of a mavservo YAML file, as pydantic v2 models.

Every model forbids unknown keys: a typo such as ``limts_deg`` must stop the process at start-up,
not leave a servo without its soft limits. Defaults are chosen so that a minimal file (one bus,
one servo, one channel) is a few lines long. Checks that need only one model live here as field
or model validators; checks that relate several sections (a channel naming a servo, CAN ids
colliding on one bus, the bus-load budget) live in :mod:`mavservo.config.semantic` so that each
problem can point at the exact key that causes it.
"""

from __future__ import annotations

import re
from pathlib import Path
from types import UnionType
from typing import Annotated, Any, Literal, Union
from typing import get_args as typing_args
from typing import get_origin as typing_origin

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    Strict,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic_core import PydanticCustomError

from mavservo.config.health_schema import HealthConfig
from mavservo.config.smallfile import SmallFileError, read_small_file
from mavservo.config.urls import url_problem
from mavservo.mavlink import TelemetryRates
from mavservo.servos import ProfileOptions, ServoProfile, get_profile, node_family
from mavservo.transport import (
    BITRATE_CODES,
    MAVLINK_CAN,
    SIM_CHANNEL,
    SIMULATED_INTERFACES,
    UnknownInterfaceError,
    interface_options,
    option_problems,
)

#: YAML reads ``yes``/``no``/``on``/``off`` as booleans and a quoted ``"3.0"`` as a string, and
#: pydantic's lax mode would quietly turn them into 1, 1.0 and 3.0 (and ``"no"`` into False), so
#: a slip such as ``max_speed_dps: yes`` would run a servo at 1 deg/s. Scalars are strict: a
#: number must be a YAML number (an integer is fine where a float is expected), a flag a YAML
#: boolean. Containers stay lax, so YAML lists still fill the tuple fields.
Float = Annotated[float, Strict()]
Int = Annotated[int, Strict()]
Bool = Annotated[bool, Strict()]

#: Names are used as dictionary keys, in log lines and in MAVLink NAMED_VALUE_FLOAT labels.
NAME_PATTERN = r"^[A-Za-z_][A-Za-z0-9_\-]*$"
Name = Annotated[str, Field(pattern=NAME_PATTERN, max_length=32)]

#: MAV_COMP_ID_SERVO1..14: the component ids a servo component may use.
SERVO_COMPONENT_IDS = range(140, 154)
#: MAV_COMP_ID_GIMBAL (154) and MAV_COMP_ID_GIMBAL2..6 (171..175).
GIMBAL_COMPONENT_IDS = (154, *range(171, 176))

#: Absolute PWM bounds a channel's input range must stay within (DO_SET_SERVO sanity range).
PWM_MIN_US = 800
PWM_MAX_US = 2200

_HEX_KEY = re.compile(r"^[0-9a-fA-F]{64}$")


#: Validation context key of a rebuild (:func:`mavservo.config.parameters.with_values`): the
#: :class:`KeptOptions` of the config it starts from.
KEPT_OPTIONS = "kept_options"


class KeptOptions:
    """The typed options of a validated config, by servo and bus name, for a rebuild of it.

    Why: a PARAM_SET validates the whole config again (its rules span sections), and each
    servo's options and each bus's node options were validated anew with it (4 + 1 options
    validations on config/dronecan.yaml for one TEL_NVF_HZ) although no parameter writes them.
    A servo or bus whose mapping is identical (same types all the way down) keeps its model.
    """

    def __init__(self, config: Config) -> None:
        self.servos = {servo.name: servo for servo in config.servos}
        self.buses = {bus.name: bus for bus in config.can.buses}

    def context(self) -> dict[str, KeptOptions]:
        return {KEPT_OPTIONS: self}


def _kept(info: ValidationInfo) -> KeptOptions | None:
    context = info.context
    kept = context.get(KEPT_OPTIONS) if isinstance(context, dict) else None
    return kept if isinstance(kept, KeptOptions) else None


def _identical(a: Any, b: Any) -> bool:
    """Equal and of the same types all the way down (``1 == 1.0 == True`` in Python, while a
    strict options model tells them apart), so a kept model is what validating would give."""
    if type(a) is not type(b):
        return False
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_identical(a[key], b[key]) for key in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(map(_identical, a, b))
    return bool(a == b)


class StrictModel(BaseModel):
    """Base for every section: unknown keys are errors, numbers are finite, models immutable."""

    model_config = ConfigDict(
        extra="forbid", frozen=True, allow_inf_nan=False, use_attribute_docstrings=True
    )


def _ordered_pair(value: tuple[float, float], what: str = "range") -> tuple[float, float]:
    low, high = value
    if not low < high:
        raise ValueError(f"{what} must be [low, high] with low < high, got [{low}, {high}]")
    return value


AngleRange = tuple[Float, Float]


# --------------------------------------------------------------------------------------- mavlink


class ComponentAddress(StrictModel):
    """A MAVLink (system, component) pair."""

    system: Int = Field(1, ge=1, le=255)
    """MAVLink system id."""
    component: Int = Field(1, ge=0, le=255)
    """MAVLink component id (0: any component of the system, where a filter allows it)."""


class AutopilotConfig(ComponentAddress):
    """The autopilot the bridge follows: its address, what it is and what the link leads to.

    ``flavour``: ``auto`` takes it from the autopilot's HEARTBEAT (MAV_AUTOPILOT 3 ArduPilot,
    12 PX4); ``ardupilot`` or ``px4`` fixes it (a HEARTBEAT saying otherwise is logged).
    ``link``: ``port`` when the bridge's link is the autopilot's own MAVLink port (it forwards
    to the ground station only the messages it knows), ``router`` for mavlink-router, MAVProxy
    or a ground station directly (everything arrives). See docs/px4.md.
    """

    flavour: Literal["auto", "ardupilot", "px4"] = "auto"
    """What the autopilot is: ``auto`` reads it from its HEARTBEAT (3 ArduPilot, 12 PX4);
    ``ardupilot`` or ``px4`` fixes it. It decides how ACTUATOR_OUTPUT_STATUS is read and which
    messages the bridge sends to it."""
    link: Literal["port", "router"] = "port"
    """What the bridge's link leads to: ``port``, the autopilot's own MAVLink port (ArduPilot
    drops messages it does not know, PX4 drops ESC_TELEMETRY_x_TO_y); ``router``, a MAVLink
    router, MAVProxy or a ground station directly (everything arrives)."""


#: Largest key file read: 64 hex characters plus whitespace fit many times over; a device or a
#: huge file is refused after this many bytes (red-team finding F).
MAX_KEY_FILE_BYTES = 4096


class SigningConfig(StrictModel):
    """MAVLink 2 signing: the 32-byte secret as 64 hex characters, inline or in a file.

    A key file holds the 64 hex characters (surrounding whitespace ignored).
    Relative paths are taken from the directory of the config file, so a config and its key can
    be moved together.
    """

    key: str | None = None
    """The signing secret inline: 64 hexadecimal characters (32 bytes). Give this or
    ``key_file``, not both."""
    key_file: Path | None = None
    """A file holding the 64 hexadecimal characters; relative to the config file's folder. Keep
    it mode 600."""
    accept_unsigned: Bool = False
    """Also accept unsigned messages from the link (a migration aid; the bridge still signs what
    it sends)."""
    max_clock_ahead_s: Annotated[Float, Field(gt=0)] | None = 60.0
    """How far ahead of this computer's clock a signed frame's timestamp may be, in seconds;
    null on a companion whose clock is not set at boot (no RTC, no NTP or GPS time), whose
    clock would otherwise make it refuse the autopilot's genuine frames."""

    @field_validator("key")
    @classmethod
    def _key_is_hex(cls, key: str | None) -> str | None:
        if key is not None and not _HEX_KEY.match(key):
            raise ValueError(
                f"expected 64 hexadecimal characters (a 32-byte key), got {len(key)} characters"
            )
        return key

    @field_validator("key_file")
    @classmethod
    def _key_file_is_readable(cls, path: Path | None, info: ValidationInfo) -> Path | None:
        if path is None:
            return None
        base_dir = (info.context or {}).get("base_dir")
        resolved = path if path.is_absolute() or base_dir is None else Path(base_dir) / path
        try:
            raw = read_small_file(resolved, MAX_KEY_FILE_BYTES)
        except SmallFileError as exc:
            hint = ""
            if not resolved.exists():
                hint = (
                    f'; make one: python3 -c "import secrets; print(secrets.token_hex(32))" > '
                    f"{resolved} && chmod 600 {resolved}, and give the autopilot the same key "
                    "(docs/hardware/ardupilot.md, MAVLink signing)"
                )
            raise ValueError(f"expected a readable key file: {exc}{hint}") from None
        if _parse_key_bytes(raw) is None:
            raise ValueError(
                f"key file {resolved} must hold 64 hex characters, found {len(raw.strip())} bytes"
            )
        return resolved

    @model_validator(mode="after")
    def _exactly_one_source(self) -> SigningConfig:
        if (self.key is None) == (self.key_file is None):
            raise ValueError("signing needs exactly one of 'key' or 'key_file'")
        return self

    def secret_key(self) -> bytes:
        """The 32-byte signing secret (reads ``key_file`` again, so a rotated key is picked up)."""
        if self.key is not None:
            return bytes.fromhex(self.key)
        assert self.key_file is not None  # guaranteed by _exactly_one_source
        try:
            key = _parse_key_bytes(read_small_file(self.key_file, MAX_KEY_FILE_BYTES))
        except SmallFileError as exc:
            raise ValueError(f"key file no longer usable: {exc}") from None
        if key is None:
            raise ValueError(f"key file {self.key_file} no longer holds a valid key")
        return key


def read_key_file(path: str | Path) -> bytes:
    """The 32-byte signing secret in a key file (64 hex characters, as ``key_file`` takes it),
    for tools outside a config (``mavservo sitl stream --signing-key-file``); ValueError says why
    a file will not do."""
    try:
        raw = read_small_file(path, MAX_KEY_FILE_BYTES)
    except SmallFileError as exc:
        raise ValueError(str(exc)) from None
    key = _parse_key_bytes(raw)
    if key is None:
        raise ValueError(f"{path} must hold 64 hex characters, found {len(raw.strip())} bytes")
    return key


def _parse_key_bytes(raw: bytes) -> bytes | None:
    text = raw.strip()
    if len(text) == 64:
        try:
            return bytes.fromhex(text.decode("ascii"))
        except (UnicodeDecodeError, ValueError):
            return None
    return None


class MirrorConfig(StrictModel):
    """Which autopilot output streams the bridge follows without an explicit command."""

    servo_output_raw: Bool = True
    """Follow the autopilot's SERVO_OUTPUT_RAW (ArduPilot's servo outputs)."""
    actuator_output_status: Bool = False
    """Follow ACTUATOR_OUTPUT_STATUS (PX4's actuator outputs)."""
    actuator_output_status_units: Literal["pwm", "normalized"] = "pwm"
    """What ACTUATOR_OUTPUT_STATUS values are: ``pwm`` (microseconds) or ``normalized`` ([-1,
    1])."""


#: The MAVLink side's own defaults: the schema takes them from there, so they are written once.
_RATES = TelemetryRates()


class TelemetryConfig(StrictModel):
    """Rates (Hz) of the MAVLink telemetry the bridge publishes; 0 turns a stream off.

    (0 rather than null, because that is what SET_MESSAGE_INTERVAL's -1/0 map onto at run time.)
    The YAML shape and its bounds; :func:`mavservo.config.views.telemetry_rates` gives the
    MAVLink side's :class:`~mavservo.mavlink.settings.TelemetryRates` of it.
    """

    actuator_output_status_hz: Float = Field(_RATES.actuator_output_status_hz, ge=0, le=100)
    """ACTUATOR_OUTPUT_STATUS with the measured positions, normalized through each channel's
    mapping (0: off)."""
    esc_telemetry_hz: Float = Field(_RATES.esc_telemetry_hz, ge=0, le=100)
    """ESC_TELEMETRY_x_TO_y per servo: temperature, current, speed (0: off). Mission Planner
    shows it."""
    named_value_float_hz: Float = Field(_RATES.named_value_float_hz, ge=0, le=100)
    """NAMED_VALUE_FLOAT per servo (``s1_pos``, ``s1_cur``, ``s1_flt``, ``s1_hlt``...; 0: off)."""
    gimbal_attitude_status_hz: Float = Field(_RATES.gimbal_attitude_status_hz, ge=0, le=100)
    """GIMBAL_DEVICE_ATTITUDE_STATUS of each gimbal (ArduPilot needs at least 5 Hz)."""
    esc_first_index: Literal["auto"] | Annotated[Int, Field(ge=1, le=29)] = _RATES.esc_first_index
    """ESC number of servo 1 in the ESC messages: 1, 5, 9, ... 29, or ``auto``: 17, above the
    motors of common frames, moving higher when the autopilot or another bridge is heard
    using those numbers."""
    name_prefix: str = Field(_RATES.name_prefix, pattern=r"^[a-z]{1,3}$")
    """First letters (1 to 3, lower case) of the NAMED_VALUE_FLOAT names: ``s`` gives
    ``s1_pos``; a second bridge on the vehicle takes another, e.g. ``t``."""

    @field_validator("esc_first_index")
    @classmethod
    def _esc_index_starts_a_message(cls, value: int | str) -> int | str:
        if isinstance(value, int) and (value - 1) % 4:
            raise ValueError(
                f"expected 1, 5, 9, ... 29 (an ESC_TELEMETRY message starts at 4k + 1), got {value}"
            )
        return value


class StreamRequestConfig(StrictModel):
    """MAV_CMD_SET_MESSAGE_INTERVAL for the mirrored streams, sent to the followed autopilot.

    ``rate_hz`` null: the scheduler's command rate (1 / ``scheduler.command_period_s``).
    ``min_rate_hz`` null: 3/4 of the requested rate; below it the bridge warns. ``enabled``
    false for an autopilot that refuses the request (the rate is still measured and reported).
    """

    enabled: Bool = True
    """Ask the followed autopilot for the mirrored streams with MAV_CMD_SET_MESSAGE_INTERVAL (at
    start, after it reboots or comes back); false for an autopilot that refuses the request
    (the rate is still measured and reported)."""
    rate_hz: Annotated[Float, Field(gt=0, le=400)] | None = None
    """The rate asked for; null: the command rate (1 / ``scheduler.command_period_s``, 20 Hz by
    default)."""
    min_rate_hz: Annotated[Float, Field(gt=0, le=400)] | None = None
    """Below this measured rate the bridge warns; null: 3/4 of the rate asked for."""

    @model_validator(mode="after")
    def _minimum_not_above_the_request(self) -> StreamRequestConfig:
        if (
            self.rate_hz is not None
            and self.min_rate_hz is not None
            and self.min_rate_hz > self.rate_hz
        ):
            raise ValueError(
                f"min_rate_hz ({self.min_rate_hz}) must be <= rate_hz ({self.rate_hz}): the "
                "bridge would warn about the rate it asked for"
            )
        return self


#: ArduPilot's SERIALn_BAUD codes below 1200 and the baud rate each stands for (ArduPilot
#: libraries/AP_SerialManager/AP_SerialManager.cpp, map_baudrate(): its switch; any other value
#: up to 2000 is taken as kbaud, so every value below 1200 is a code there).
ARDUPILOT_BAUD_CODES = {
    1: 1200,
    2: 2400,
    4: 4800,
    9: 9600,
    19: 19200,
    38: 38400,
    57: 57600,
    100: 100000,
    111: 111100,
    115: 115200,
    230: 230400,
    256: 256000,
    460: 460800,
    500: 500000,
    921: 921600,
}


class MavlinkConfig(StrictModel):
    """The MAVLink side: where the autopilot is and how the bridge presents itself."""

    url: str = "sim"
    """Where the autopilot is, as a pymavlink connection string: ``udpin:0.0.0.0:14551``,
    ``udpout:HOST:PORT``, ``tcp:HOST:PORT``, a serial device such as ``/dev/ttyAMA0`` or
    ``/dev/serial0``; ``sim`` (also when the key is left out) starts the built-in simulated
    autopilot, which never drives a bus that reaches hardware (only ``channel: sim`` and
    software buses such as python-can's ``virtual``): with a real bus it is an error."""
    baud: Int = Field(115200, gt=0)
    """Serial links only: the baud rate in bit/s, the one the autopilot's ``SERIALn_BAUD`` names
    (``SERIALn_BAUD`` 921 is ``baud: 921600``)."""
    system_id: Literal["follow"] | Annotated[Int, Field(ge=1, le=255)] = "follow"
    """The bridge's MAVLink system id: ``follow`` takes the autopilot's, or a fixed 1..255."""
    servo_component_id: Int = 140
    """The MAVLink component the servos are published as: 140..153 (MAV_COMP_ID_SERVO1..14); a
    second bridge on the vehicle takes another."""
    servo_output_port_width: Literal[8, 16] = 16
    """Channels per SERVO_OUTPUT_RAW ``port``: 16 is what ArduPilot sends over MAVLink 2, 8 for
    MAVLink 1 senders."""
    autopilot: AutopilotConfig = AutopilotConfig()
    """The autopilot whose HEARTBEAT the bridge watches (failsafe) and whose streams it follows:
    its address, its ``flavour`` (auto, ardupilot, px4) and what the ``link`` leads to (port,
    router)."""
    heartbeat_timeout_s: Float = Field(2.0, gt=0)
    """Autopilot silent this long: the link is lost, and each servo takes its ``failsafe``
    action after its own ``failsafe.timeout_s``."""
    signing: SigningConfig | None = None
    """MAVLink 2 signing; null: no signing (anyone on the link may command)."""
    allowed_sources: list[ComponentAddress] = []
    """Senders (system, component) allowed to command; empty: anyone. A filter, not
    authentication: use ``signing`` for that."""
    parameter_writers: Literal["verified", "anyone"] = "verified"
    """Who may set the bridge's parameters from a ground station: ``verified`` (a signed sender,
    or one in ``allowed_sources``) or ``anyone`` (a bench)."""
    act_on_autopilot_commands: Bool = False
    """Also act on DO_SET_SERVO addressed to the autopilot (not to the bridge), for mapped
    channels, without an ACK of its own."""
    repeat_servo_cycle: Literal["seconds", "milliseconds"] = "seconds"
    """Unit of DO_REPEAT_SERVO's cycle time (param 4): ``seconds``, as the MAVLink specification
    says, or ``milliseconds`` for a sender that uses them."""
    command_hold_s: Float = Field(2.0, ge=0)
    """After an explicit command (DO_SET_SERVO, DO_SET_ACTUATOR...), mirroring the autopilot's
    outputs waits this long before it moves that servo again."""
    mirror: MirrorConfig = MirrorConfig()
    """Which autopilot output streams the bridge follows."""
    telemetry: TelemetryConfig = TelemetryConfig()
    """What the bridge publishes about the servos, in Hz."""
    request_streams: StreamRequestConfig = StreamRequestConfig()
    """How the bridge asks the autopilot for the streams it follows."""
    monitor_outputs: list[str] = []
    """Output-only endpoints (``udpout:HOST:PORT``) that get a copy of everything the bridge
    sends, for ``mavservo monitor``."""
    link_budget_bytes_s: Annotated[Float, Field(gt=0)] | None = 1000.0
    """Bytes per second the periodic telemetry may use on the autopilot link, which ArduPilot
    forwards to the ground station's radio (a 57,600-baud radio carries about 5,700 B/s in
    all): the rates are scaled down to fit; null: no budget (a wired link)."""

    @field_validator("url")
    @classmethod
    def _url_is_a_connection_string(cls, url: str) -> str:
        problem = url_problem(url)
        if problem is not None:
            raise ValueError(problem)
        return url

    @field_validator("baud")
    @classmethod
    def _baud_is_in_bits_per_second(cls, baud: int) -> int:
        # ArduPilot's SERIALn_BAUD takes codes in thousands (ARDUPILOT_BAUD_CODES: 921 ->
        # 921600); a MAVLink link below 1200 baud is that code copied, silent rather than slow.
        if baud < 1200:
            hint = ""
            if baud in ARDUPILOT_BAUD_CODES:
                hint = (
                    f": ArduPilot's SERIALn_BAUD {baud} is {ARDUPILOT_BAUD_CODES[baud]} baud; "
                    f"write baud: {ARDUPILOT_BAUD_CODES[baud]}"
                )
            raise ValueError(f"expected a baud rate in bit/s (1200 or more), got {baud}{hint}")
        return baud

    @field_validator("monitor_outputs")
    @classmethod
    def _monitor_outputs_are_endpoints(cls, urls: list[str]) -> list[str]:
        for url in urls:
            problem = url_problem(url, allow_sim=False)
            if problem is not None:
                raise ValueError(problem)
        return urls

    @field_validator("servo_component_id")
    @classmethod
    def _servo_component_range(cls, value: int) -> int:
        if value not in SERVO_COMPONENT_IDS:
            raise ValueError(
                f"expected a servo component id in 140..153 (MAV_COMP_ID_SERVO1..14), got {value}"
            )
        return value


# ------------------------------------------------------------------------------------------- CAN


def raise_option_problems(problems: list[tuple[str, str]], field: str = "options") -> None:
    """Raise the ``(key, message)`` problems of a mapping of options (``field``: a servo's
    ``options``, a bus's ``node``) as one error the loader splits again, so that each is
    reported on its own key's line."""
    if problems:
        raise PydanticCustomError(
            "profile_options",
            "{summary}",
            {
                "summary": "; ".join(f"{field}.{k}: {m}" for k, m in problems),
                "problems": problems,
                "field": field,
            },
        )


class BusConfig(StrictModel):
    """One CAN bus: the project's ``aa55`` adapter, or any python-can interface."""

    name: Name = "bus0"
    """The bus's name, which ``servos[].bus`` refers to."""
    interface: str = "aa55"
    """``aa55`` (the AA-55 USB-CAN adapter: Waveshare USB-CAN-A, Seeed) or any python-can
    interface: ``socketcan``, ``slcan``, ``gs_usb``, ``pcan``..."""
    channel: str | Int = "sim"
    """The device: a serial port for ``aa55`` and ``slcan`` (``/dev/ttyUSB0``,
    ``/dev/ttyACM0``), a network interface for ``socketcan`` (``can0``), ``PCAN_USBBUS1`` for
    ``pcan``; ``sim``: the built-in simulated adapter and servos (``aa55`` and ``slcan``)."""
    bitrate: Int = Field(1_000_000, gt=0)
    """CAN bit rate in bit/s, the servos' (aa55: 1000000, 800000, 500000, 400000, 250000,
    200000, 125000, 100000, 50000, 20000, 10000, 5000). SocketCAN takes it from ``ip link``:
    here it is used for the bus-load budget."""
    serial_baud: Int = Field(2_000_000, gt=0)
    """aa55 only: the USB serial speed of the adapter."""
    protocol: Literal["variable", "fixed"] = "variable"
    """aa55 only: the framing on the USB line: ``variable`` (the adapter's everyday frames, no
    checksum) or ``fixed`` (20-byte frames with a checksum: for a noisy or long USB line)."""
    read_interval_s: Literal["auto"] | Annotated[Float, Field(ge=0, le=0.05)] = "auto"
    """aa55 only: least time between two reads of the adapter in seconds; ``auto``: none while
    the line is lightly used, up to 8 ms while it is busy (saves CPU under a flood)."""
    max_load: Float = Field(0.35, gt=0, le=1)
    """The bus-load budget R_max (0..1): a config whose worst-case load is above it is refused."""
    options: dict[str, Any] = Field(default_factory=dict)
    """Passed to the python-can interface as keyword arguments (slcan's ``tty_baudrate`` and
    ``sleep_after_open``, pcan's ``auto_reset``...), checked against what that interface
    accepts."""
    node: dict[str, dict[str, Any]] = Field(default_factory=dict)
    """The bridge's own node on this bus, per servo family that has one, keyed by profile name:
    ``{dronecan: {node_id: 100}}`` (see the DroneCAN bus node options below)."""

    _node_options: tuple[dict[str, dict[str, Any]], dict[str, ProfileOptions]] | None = PrivateAttr(
        None
    )
    """``(node mapping, typed)``: ``node`` as each family's ``NodeOptions``, validated once by
    :meth:`_node_options_valid`, with what it was validated from."""

    @model_validator(mode="after")
    def _node_options_valid(self, info: ValidationInfo) -> BusConfig:
        """Each ``node:`` entry checked by its family's ``NodeOptions``, once, and kept typed;
        each problem on its own key's line. A rebuild (:data:`KEPT_OPTIONS` in the context)
        takes the typed options of the same bus when its ``node`` is unchanged."""
        kept = _kept(info)
        prior = None if kept is None else kept.buses.get(self.name)
        if (
            prior is not None
            and prior._node_options is not None
            and _identical(prior.node, self.node)
        ):
            self._node_options = (self.node, prior._node_options[1])
            return self
        self._keep_node_options()
        return self

    def _keep_node_options(self) -> None:
        problems: list[tuple[str, str]] = []
        typed: dict[str, ProfileOptions] = {}
        for name, options in self.node.items():
            family = node_family(get_profile(name))
            if family is None:
                problems.append((name, f"profile {name!r} has no bus node"))
                continue
            try:
                typed[name] = family.NodeOptions.model_validate(options)
            except ValidationError as exc:
                problems += [
                    (
                        ".".join((name, *(str(p) for p in e["loc"]))),
                        f"{e['msg']}, found {e.get('input')!r}",
                    )
                    for e in exc.errors(include_url=False)
                ]
        raise_option_problems(problems, "node")
        self._node_options = (self.node, typed)

    def node_options(self) -> dict[str, ProfileOptions]:
        """The bridge's node options on this bus by profile name, as validated from ``node``
        (a family without an entry takes its ``NodeOptions`` defaults). A copy made with
        another ``node`` (``model_copy(update=...)`` skips validation) is validated here."""
        if self._node_options is None or self._node_options[0] is not self.node:
            self._keep_node_options()
        assert self._node_options is not None
        return dict(self._node_options[1])

    @field_validator("interface")
    @classmethod
    def _known_interface(cls, interface: str) -> str:
        try:
            interface_options(interface)
        except UnknownInterfaceError as exc:
            raise ValueError(str(exc)) from None
        return interface

    @field_validator("channel")
    @classmethod
    def _simulation_exists(cls, channel: str | int, info: ValidationInfo) -> str | int:
        interface = info.data.get("interface")
        if interface == MAVLINK_CAN and not (isinstance(channel, int) and 1 <= channel <= 3):
            raise ValueError(
                "interface mavlink-can: channel is the autopilot's CAN bus number, 1..3 as in "
                f"CAN_P1..CAN_P3 (the bus is reached through mavlink.url), got {channel!r}"
            )
        simulated = interface is None or interface in SIMULATED_INTERFACES
        if channel == SIM_CHANNEL and not simulated:
            names = " and ".join(SIMULATED_INTERFACES)
            raise ValueError(
                f"channel 'sim' is the built-in simulation, which only {names} have; give "
                f"the {interface} device (e.g. can0, PCAN_USBBUS1)"
            )
        return channel

    @model_validator(mode="after")
    def _options_accepted(self) -> BusConfig:
        """Each problem on its own key's line (the loader expands ``profile_options``)."""
        raise_option_problems(option_problems(self.interface, self.options))
        return self

    @field_validator("bitrate")
    @classmethod
    def _aa55_bitrate_has_a_code(cls, bitrate: int, info: ValidationInfo) -> int:
        """A field validator, not a model one, so the error is reported at the ``bitrate`` key's
        line rather than the bus's (``interface``, declared above, is validated first)."""
        # the codec's table is the one list of what the adapter can do: ask it, keep no copy
        if info.data.get("interface") == "aa55" and bitrate not in BITRATE_CODES:
            codes = ", ".join(str(rate) for rate in BITRATE_CODES)
            raise ValueError(f"an aa55 adapter supports bitrates {codes}; got {bitrate}")
        return bitrate


class CanConfig(StrictModel):
    buses: list[BusConfig] = Field(default_factory=lambda: [BusConfig()], min_length=1)
    """One entry per CAN bus (adapter)."""


# ---------------------------------------------------------------------------------------- servos


class FailsafeConfig(StrictModel):
    """What a servo does when its commands stop (link lost, autopilot silent, shutdown).

    ``hold`` keeps the last target, ``neutral`` goes to the servo's ``neutral_deg``, ``position``
    goes to ``position_deg``, ``release`` stops commanding (motor off, if the profile can).
    ``timeout_s`` is how long after the autopilot link is declared lost (``mavlink.
    heartbeat_timeout_s``) this servo waits before acting, so a throttle can idle at once while
    surfaces hold a moment longer; on shutdown every action is immediate.
    """

    action: Literal["hold", "neutral", "position", "release"] = "hold"
    """What the servo does when its commands stop (autopilot link lost, shutdown): ``hold`` the
    last target, go to ``neutral_deg``, go to ``position`` (``position_deg``), or ``release``
    (motor off; only for families with a motor-off frame)."""
    position_deg: Float | None = None
    """The angle of ``action: position``."""
    timeout_s: Float = Field(1.0, gt=0)
    """How long after the link is declared lost the servo waits before acting (a throttle may
    idle at once while surfaces hold a moment longer); on shutdown every action is immediate."""

    @model_validator(mode="after")
    def _position_needs_an_angle(self) -> FailsafeConfig:
        if self.action == "position" and self.position_deg is None:
            raise ValueError("failsafe action 'position' needs position_deg")
        return self


#: The largest id range searched for a frame id written as ``can_id`` (CubeMars: 0..255).
_HINT_IDS = 256


def frame_id_hint(profile: type[ServoProfile], name: str, value: int) -> str:
    """When an out-of-range ``can_id`` is the CAN frame id of one of the family's servos (an
    RMD-X's ``0x141`` is servo 1's request, ``0x140 + id``), what to write instead; else ``""``.
    The profile's own :meth:`~mavservo.servos.ServoProfile.identifiers` say it, no table here."""
    ids = range(profile.min_id, profile.max_id + 1)
    if len(ids) > _HINT_IDS:
        return ""
    for servo_id in ids:
        try:
            frames = profile(servo_id).identifiers()
        except Exception:  # noqa: BLE001 - a profile that cannot be built bare gives no hint
            return ""
        for frame in frames:
            if (
                frame.arbitration_id == value
                and frame.direction == "to_servo"
                and frame.id_mask == -1
                and not frame.shared
            ):
                return (
                    f" (0x{value:X}): that is the {frame.purpose} frame id of {name} servo "
                    f"{servo_id} on the bus, not a servo id; write `can_id: {servo_id}`"
                )
    return ""


class ServoConfig(StrictModel):
    """One CAN servo. ``bus`` may be omitted when there is exactly one bus.

    ``profile`` is any name the profile registry knows (built-in or plug-in), ``can_id`` must be
    in that profile's id range, and ``options`` is checked by the profile's own ``Options``
    model once, here (each problem with its key, so the loader prints its line); the typed
    options are kept (:meth:`profile_options`), so no other layer parses them again.
    """

    name: Name
    """A unique name (letters, digits, ``_``, ``-``; at most 32), used in logs, telemetry and
    ``channels``."""
    profile: str
    """The servo family: ``rmd-x``, ``lk``, ``cubemars-ak``, ``cubemars-ak-mit``, ``damiao-dm``,
    ``robstride``, ``odrive``, ``dronecan``, or a plug-in's name (``mavservo check
    --profiles`` lists them)."""
    can_id: Int = Field(ge=0, le=0x1FFFFFFF)
    """The servo's id on the bus, in its family's range (``mavservo check --profiles``;
    DroneCAN: the node id)."""
    bus: Name | None = None
    """The ``can.buses[].name`` it hangs on; may be left out when there is one bus."""
    max_speed_dps: Float = Field(360.0, gt=0)
    """Speed limit sent with every position command, deg/s."""
    limits_deg: AngleRange = (-180.0, 180.0)
    """Soft limits [low, high] in degrees: no command ever goes beyond them."""
    neutral_deg: Float = 0.0
    """Where failsafe ``neutral`` goes (inside ``limits_deg``)."""
    command_mode: Literal["periodic", "immediate"] = "periodic"
    """``periodic``: a command per command period; ``immediate``: sent on arrival (at most one
    per ``scheduler.immediate_min_spacing_s``)."""
    telemetry_hz: Float = Field(10.0, gt=0)
    """How often the servo is polled, or (push-style families) how often it reports on its own:
    it is offline after a few missed reports."""
    failsafe: FailsafeConfig = FailsafeConfig()
    """What the servo does when commands stop."""
    options: dict[str, Any] = Field(default_factory=dict)
    """Family options, checked by the profile (see the options by profile below)."""
    health: HealthConfig = HealthConfig()
    """Thresholds of the bridge's own health checks of this servo (every key optional; defaults
    derived from the servo, printed by ``mavservo check``)."""

    @field_validator("limits_deg")
    @classmethod
    def _limits_ordered(cls, value: AngleRange) -> AngleRange:
        return _ordered_pair(value, "limits_deg")

    @field_validator("profile")
    @classmethod
    def _registered_profile(cls, value: str) -> str:
        get_profile(value)  # raises with the known names and where plug-ins come from
        return value

    @field_validator("can_id")
    @classmethod
    def _id_fits_profile(cls, value: int, info: ValidationInfo) -> int:
        name = info.data.get("profile")
        if name is None:
            return value  # reported as an unknown profile
        profile = get_profile(name)
        if not profile.min_id <= value <= profile.max_id:
            raise ValueError(
                f"{name} servo ids are {profile.min_id}..{profile.max_id}, got {value}"
                + frame_id_hint(profile, name, value)
            )
        return value

    _options: tuple[str, dict[str, Any], ProfileOptions] | None = PrivateAttr(None)
    """``(profile, options mapping, typed options)``: ``options`` validated once by
    :meth:`_options_valid`, with what it was validated from."""

    @model_validator(mode="after")
    def _options_valid(self, info: ValidationInfo) -> ServoConfig:
        """``options`` checked by the profile's ``Options``, once, and kept typed. A rebuild
        (:data:`KEPT_OPTIONS` in the context) takes the typed options of the same servo when
        its profile and options are unchanged: a PARAM_SET never writes options, so validating
        them again would give the same immutable model."""
        kept = _kept(info)
        prior = None if kept is None else kept.servos.get(self.name)
        if (
            prior is not None
            and prior._options is not None
            and prior.profile == self.profile
            and _identical(prior.options, self.options)
        ):
            self._options = (self.profile, self.options, prior._options[2])
            return self
        model = get_profile(self.profile).Options
        try:
            self._options = (self.profile, self.options, model.model_validate(self.options))
        except ValidationError as exc:
            raise_option_problems(
                [_option_problem(model, error) for error in exc.errors(include_url=False)]
            )
        return self

    def profile_options(self) -> ProfileOptions:
        """The validated ``options`` as the profile's ``Options`` instance (built once, when
        the config was validated; options models are immutable, so it is shared). A copy
        made with other options or another profile (``model_copy(update=...)``, which skips
        validation) has them validated here, once."""
        kept = self._options
        if kept is None or kept[0] != self.profile or kept[1] is not self.options:
            model = get_profile(self.profile).Options
            kept = self._options = (self.profile, self.options, model.model_validate(self.options))
        return kept[2]

    def make_profile(self) -> ServoProfile:
        """A new profile instance for this servo (its id and its validated options): each
        scheduler, check and simulator gets its own, since a profile keeps per-servo state."""
        profile = get_profile(self.profile)(self.can_id, self.profile_options())
        profile.telemetry_hz = self.telemetry_hz
        return profile

    @model_validator(mode="after")
    def _angles_inside_limits(self) -> ServoConfig:
        low, high = self.limits_deg
        if not low <= self.neutral_deg <= high:
            raise ValueError(
                f"neutral_deg {self.neutral_deg} is outside limits_deg [{low}, {high}]"
            )
        return self


def _option_problem(model: type[BaseModel], error: Any) -> tuple[str, str]:
    key = ".".join(str(part) for part in error["loc"]) or "options"
    field = model.model_fields.get(str(error["loc"][0])) if error["loc"] else None
    if error["type"] == "extra_forbidden":
        allowed = ", ".join(model.model_fields) or "none (this profile takes no options)"
        return key, f"unknown option {key!r}; allowed options: {allowed}"
    message = f"{error['msg']}, found {error.get('input')!r}"
    if field is not None:
        message += f" (allowed: {allowed_values(field)}; default {default_text(field.default)})"
    return key, message


#: Python types in the words of a YAML user (``check --profiles``, option errors).
_TYPE_WORDS: dict[type, str] = {
    bool: "true or false",
    int: "a whole number",
    float: "a number",
    str: "text",
    dict: "a mapping",
    list: "a list",
    tuple: "a list",
    Path: "a file path",
}


def _members(annotation: Any) -> list[Any]:
    """A union's members (Annotated unwrapped), or the annotation itself."""
    origin = typing_origin(annotation)
    if origin is Annotated:
        return _members(typing_args(annotation)[0])
    if origin in (Union, UnionType):
        return [m for arg in typing_args(annotation) for m in _members(arg)]
    return [annotation]


def _type_words(annotation: Any) -> tuple[str, bool]:
    """``(words, optional)``: what a value of ``annotation`` is (``one of: a, b``, ``a whole
    number``), and whether null is allowed too."""
    members = _members(annotation)
    optional = type(None) in members
    members = [m for m in members if m is not type(None)]
    choices = [choice for m in members if typing_origin(m) is Literal for choice in typing_args(m)]
    others = [m for m in members if typing_origin(m) is not Literal]
    words = []
    if choices:
        words.append("one of: " + ", ".join(str(c) for c in choices))
    for member in others:
        base = typing_origin(member) or member
        word = _TYPE_WORDS.get(base, getattr(base, "__name__", str(base)))
        if word not in words:
            words.append(word)
    return " or ".join(words) or "anything", optional


def default_text(value: Any) -> str:
    """A default as a YAML file would write it: ``null``, ``false``, ``MF``, ``1000``."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (dict, list, tuple)) and not value:
        return "{}" if isinstance(value, dict) else "[]"
    return str(value)


def allowed_values(field: Any) -> str:
    """A field's bounds as ``1..40`` or ``> 0``, its choices (``one of: a, b``), or its kind
    (``text``, ``true or false``), with ``, optional`` when null is allowed."""
    low = high = None
    low_open = high_open = False
    for rule in field.metadata:
        for attr, is_low, is_open in (("ge", 1, 0), ("gt", 1, 1), ("le", 0, 0), ("lt", 0, 1)):
            value = getattr(rule, attr, None)
            if value is None:
                continue
            if is_low:
                low, low_open = value, bool(is_open)
            else:
                high, high_open = value, bool(is_open)
    words, optional = _type_words(field.annotation)
    suffix = ", optional" if optional else ""
    if low is None and high is None or words.startswith("one of"):
        return words + suffix
    left = f"{'>' if low_open else '>='} {low}" if low is not None else ""
    right = f"{'<' if high_open else '<='} {high}" if high is not None else ""
    if low is not None and high is not None and not low_open and not high_open:
        return f"{low}..{high}{suffix}"
    return " and ".join(part for part in (left, right) if part) + suffix


# -------------------------------------------------------------------------------------- channels


class PwmInput(StrictModel):
    """A PWM input range in microseconds; ``trim`` defaults to the middle."""

    min: Float = 1100
    """PWM (us) that maps to the low end of ``output_deg`` (the high end when ``reverse``)."""
    max: Float = 1900
    """PWM (us) that maps to the high end of ``output_deg``."""
    trim: Float | None = None
    """PWM (us) that maps to the centre of ``output_deg`` (plus ``trim_deg``); null: the middle
    of min and max."""

    @model_validator(mode="after")
    def _ordered(self) -> PwmInput:
        trim = self.resolved_trim
        if not PWM_MIN_US <= self.min < trim < self.max <= PWM_MAX_US:
            raise ValueError(
                f"expected {PWM_MIN_US} <= min < trim < max <= {PWM_MAX_US}, "
                f"got min {self.min}, trim {trim}, max {self.max}"
            )
        return self

    @property
    def resolved_trim(self) -> float:
        return (self.min + self.max) / 2 if self.trim is None else self.trim


class NormalizedInput(StrictModel):
    """A normalized input range (DO_SET_ACTUATOR values); defaults are the full [-1, 1]."""

    min: Float = -1.0
    """Input value that maps to the low end of ``output_deg``."""
    max: Float = 1.0
    """Input value that maps to the high end of ``output_deg``."""
    trim: Float | None = None
    """Input value that maps to the centre of ``output_deg``; null: the middle of min and max."""

    @model_validator(mode="after")
    def _ordered(self) -> NormalizedInput:
        trim = self.resolved_trim
        if not -1.0 <= self.min < trim < self.max <= 1.0:
            raise ValueError(
                "expected -1 <= min < trim < max <= 1, "
                f"got min {self.min}, trim {trim}, max {self.max}"
            )
        return self

    @property
    def resolved_trim(self) -> float:
        return (self.min + self.max) / 2 if self.trim is None else self.trim


class _ChannelCommon(StrictModel):
    servo: Name
    """The servo this input drives (a ``servos[].name``)."""
    output_deg: AngleRange | None = None  # None: the servo's limits_deg
    """Angle range [low, high] the input range maps onto; null: the servo's ``limits_deg``."""
    reverse: Bool = False
    """Reverse the mapping: the input's min gives the high angle."""
    trim_deg: Float = 0.0
    """Shifts the angle the input's trim maps to, in degrees (a ground station can set it:
    ``SRVn_TRIM``)."""
    max_slew_dps: Float | None = Field(None, gt=0)
    """Rate limit on the target, deg/s; null: none."""

    @field_validator("output_deg")
    @classmethod
    def _output_ordered(cls, value: AngleRange | None) -> AngleRange | None:
        return None if value is None else _ordered_pair(value, "output_deg")

    @model_validator(mode="after")
    def _trim_inside_output(self) -> _ChannelCommon:
        if self.output_deg is not None:
            low, high = self.output_deg
            centre = (low + high) / 2 + self.trim_deg
            if not low < centre < high:
                raise ValueError(
                    f"trim_deg {self.trim_deg} moves the centre ({centre}) outside output_deg "
                    f"({low}, {high})"
                )
        return self


class ServoOutputChannel(_ChannelCommon):
    """A MAVLink servo output channel: SERVO_OUTPUT_RAW mirroring and DO_SET_SERVO, PWM in us.

    ``channel`` is 1-based; channels 17..32 arrive as SERVO_OUTPUT_RAW port 1.
    """

    source: Literal["servo_output"]
    """``servo_output``: the autopilot's servo output channel (SERVO_OUTPUT_RAW, DO_SET_SERVO,
    DO_REPEAT_SERVO), PWM input."""
    channel: Int = Field(ge=1, le=32)
    """The output channel, 1..32 (ArduPilot's ``SERVOn``: channels 17..32 come as
    SERVO_OUTPUT_RAW port 1)."""
    input: PwmInput = PwmInput()
    """The PWM input range."""

    @property
    def key(self) -> int:
        return self.channel


class ActuatorChannel(_ChannelCommon):
    """A DO_SET_ACTUATOR / ACTUATOR_OUTPUT_STATUS index (1-based), normalized input."""

    source: Literal["actuator"]
    """``actuator``: an actuator index (DO_SET_ACTUATOR, PX4's ACTUATOR_OUTPUT_STATUS),
    normalized input."""
    index: Int = Field(ge=1, le=32)
    """The actuator number, 1..32 (DO_SET_ACTUATOR set 0 is actuators 1..6)."""
    input: NormalizedInput = NormalizedInput()
    """The normalized input range."""

    @property
    def key(self) -> int:
        return self.index


ChannelConfig = Annotated[ServoOutputChannel | ActuatorChannel, Field(discriminator="source")]


# --------------------------------------------------------------------------------------- gimbals


class GimbalLimits(StrictModel):
    """Per-axis angle limits of a gimbal group; an omitted axis takes its servo's limits."""

    roll: AngleRange | None = None
    """Roll limits [low, high], deg; null: the roll servo's ``limits_deg``."""
    pitch: AngleRange | None = None
    """Pitch limits [low, high], deg; null: the pitch servo's ``limits_deg``."""
    yaw: AngleRange | None = None
    """Yaw limits [low, high], deg; null: the yaw servo's ``limits_deg``."""

    @field_validator("roll", "pitch", "yaw")
    @classmethod
    def _ordered(cls, value: AngleRange | None) -> AngleRange | None:
        return None if value is None else _ordered_pair(value)


class GimbalConfig(StrictModel):
    """A gimbal device (protocol v2) made of up to three servos."""

    name: Name
    """A unique name."""
    component_id: Int = 154
    """The gimbal's MAVLink component: 154 (MAV_COMP_ID_GIMBAL) or 171..175."""
    roll: Name | None = None
    """The servo that turns roll; leave out an axis the gimbal does not have."""
    pitch: Name | None = None
    """The servo that turns pitch."""
    yaw: Name | None = None
    """The servo that turns yaw (body frame; earth-frame targets are converted)."""
    limits_deg: GimbalLimits = GimbalLimits()
    """Per-axis limits (a ground station may narrow them: ``GMBn_*``)."""
    act_as_manager: Bool = False
    """Also be the gimbal manager, for an autopilot without a mount backend (ArduPilot with
    ``MNT1_TYPE 6`` is the manager: leave false)."""
    retract_pose_deg: tuple[Float, Float, Float] | None = None
    """[roll, pitch, yaw] for RETRACT; null: the built-in stowed pose."""
    neutral_pose_deg: tuple[Float, Float, Float] = (0.0, 0.0, 0.0)
    """[roll, pitch, yaw] for NEUTRAL."""
    vendor_name: str = Field("mavservo", max_length=32)
    """Reported in GIMBAL_DEVICE_INFORMATION (at most 32 characters)."""
    model_name: str = Field("CAN servo gimbal", max_length=32)
    """Reported in GIMBAL_DEVICE_INFORMATION (at most 32 characters)."""

    @field_validator("component_id")
    @classmethod
    def _gimbal_component_range(cls, value: int) -> int:
        if value not in GIMBAL_COMPONENT_IDS:
            raise ValueError(f"expected a gimbal component id, 154 or 171..175, got {value}")
        return value

    @model_validator(mode="after")
    def _has_an_axis(self) -> GimbalConfig:
        if not self.axes():
            raise ValueError("a gimbal needs at least one of roll, pitch, yaw")
        return self

    def axes(self) -> dict[str, str]:
        """Axis name -> servo name, for the axes present."""
        named = {"roll": self.roll, "pitch": self.pitch, "yaw": self.yaw}
        return {axis: servo for axis, servo in named.items() if servo is not None}


# ------------------------------------------------------------------------------------- scheduler


class SchedulerConfig(StrictModel):
    """Timing of the dual-loop scheduler (paper: T_c = 50 ms, telemetry 80-100 ms)."""

    command_period_s: Float = Field(0.05, gt=0)
    """Command loop period T_c, s: every periodic servo gets a command slot this often."""
    telemetry_period_s: Float = Field(0.09, gt=0)
    """Telemetry polling loop period, s (suspended while commands go out)."""
    refresh_interval_s: Float = Field(0.2, gt=0)
    """Re-send the last command this often when nothing new comes (keep-alive), s; at least
    ``command_period_s``."""
    immediate_min_spacing_s: Float = Field(0.005, gt=0)
    """Least gap between two commands of an ``immediate`` servo, s."""
    reply_timeout_s: Float = Field(0.05, gt=0)
    """A reply later than this counts as missed, s; several missed in a row and the servo is
    offline."""
    realtime: Bool = False
    """Ask for SCHED_FIFO real-time priority (needs root or CAP_SYS_NICE; the bridge says so and
    runs on when refused)."""

    @model_validator(mode="after")
    def _refresh_not_faster_than_commands(self) -> SchedulerConfig:
        if self.refresh_interval_s < self.command_period_s:
            raise ValueError(
                f"refresh_interval_s ({self.refresh_interval_s}) must be >= command_period_s "
                f"({self.command_period_s}): a refresh re-sends the last command"
            )
        return self


# ------------------------------------------------------------------------------------ simulation


class SimAutopilotConfig(StrictModel):
    """The built-in autopilot stream simulator (used when ``mavlink.url`` is ``sim``).

    ``script`` is a list of timed events in :mod:`mavservo.config.autopilot_script`'s format,
    checked here with the
    simulator's own parser so a bad event is reported with its line.
    """

    profile: Literal["sweep", "steps", "staircase", "hold", "random-walk", "replay"] = "sweep"
    """What the simulated autopilot's outputs do: ``sweep``, ``steps``, ``staircase``, ``hold``,
    ``random-walk``, or ``replay`` a recorded .tlog."""
    servo_output_rate_hz: Float = Field(20.0, gt=0)
    """SERVO_OUTPUT_RAW rate, Hz."""
    replay_file: Path | None = None  # a .tlog, for profile "replay"
    """The .tlog of ``profile: replay``."""
    speed: Float = Field(1.0, gt=0)  # replay speed factor
    """Replay speed factor."""
    seed: Int = 0  # random-walk seed
    """Seed of ``random-walk``."""
    gimbal: Bool = False  # also act as a gimbal manager sending SET_ATTITUDE
    """Also act as a gimbal manager, sending gimbal attitudes as ArduPilot's mount backend does."""
    autopilot: Literal["ardupilot", "px4"] = "ardupilot"
    """Which autopilot to simulate: ArduPlane's companion port, or PX4's onboard link (with
    PX4's defaults: ACTUATOR_OUTPUT_STATUS.active as a count, gimbal setpoints at 5 Hz)."""
    command_target: tuple[Int, Int] = (1, 0)  # (system, component) commands are addressed to
    """[system, component] the script's commands are addressed to (component 0: broadcast)."""
    script: list[dict[str, Any]] = []
    """Mission-style commands at given times: ``{at: 1.0, do_set_servo: {channel: 5, pwm:
    1700}}``, ``do_repeat_servo``, ``do_set_actuator`` (see ``config/sim.yaml``)."""

    @field_validator("script")
    @classmethod
    def _script_parses(cls, script: list[dict[str, Any]]) -> list[dict[str, Any]]:
        from mavservo.config.autopilot_script import (
            parse_script,  # the simulator owns the event format
        )

        try:
            parse_script(script)
        except (ValueError, TypeError, KeyError) as exc:
            raise ValueError(f"bad simulation script: {exc}") from None
        return script

    @model_validator(mode="after")
    def _replay_needs_a_file(self) -> SimAutopilotConfig:
        if self.profile == "replay" and self.replay_file is None:
            raise ValueError("profile 'replay' needs replay_file")
        return self


SimValue = float | int | bool | str | None


class SimServoConfig(StrictModel):
    """Physics and fault injection of one simulated servo, in :mod:`mavservo.config.simulation`
    terms."""

    physics: dict[str, SimValue] = {}
    """The simulated servo's mechanics and thermals (keys listed below)."""
    faults: dict[str, SimValue] = {}
    """Faults injected into the simulated servo (keys listed below)."""
    can_id: Int | None = Field(None, ge=0, le=0x1FFFFFFF)
    """An injected wiring mistake: the id the simulated servo really has (``mavservo doctor``
    finds it)."""
    profile: str | None = None
    """An injected mistake: the protocol (profile name) the simulated servo really speaks."""
    options: dict[str, Any] | None = None
    """An injected mistake: the options the simulated servo really has (e.g. another mode)."""

    @field_validator("profile")
    @classmethod
    def _wired_profile(cls, value: str | None) -> str | None:
        if value is not None:
            get_profile(value)
        return value

    @field_validator("physics")
    @classmethod
    def _known_physics(cls, values: dict[str, SimValue]) -> dict[str, SimValue]:
        from mavservo.config.simulation import Physics

        Physics.from_dict(values)
        return values

    @field_validator("faults")
    @classmethod
    def _known_faults(cls, values: dict[str, SimValue]) -> dict[str, SimValue]:
        from mavservo.config.simulation import Faults

        Faults.from_dict(values)
        return values


class SimulationConfig(StrictModel):
    """Only used by ``sim`` endpoints.

    ``servos`` maps a servo name (or ``default``, for all the others) to its simulated physics
    and injected faults.
    """

    autopilot: SimAutopilotConfig = SimAutopilotConfig()
    """The simulated autopilot (used when ``mavlink.url`` is ``sim``)."""
    servos: dict[str, SimServoConfig] = {}
    """Per servo name (or ``default`` for the others): its simulated physics and injected
    faults."""
    bus_bitrates: dict[str, Annotated[Int, Field(gt=0)]] = {}
    """An injected mistake: the bit rate the simulated servos of a bus really run at, by bus
    name."""


# --------------------------------------------------------------------------------------- logging


class LoggingConfig(StrictModel):
    """Where a run's records go: CAN logs (python-can writers), MAVLink tlog, text log."""

    dir: Path = Path("runs")
    """Where run directories go (one per run; relative to the working directory)."""
    # Both by default, as the README promises: ASC for reading by eye and diffing, BLF for
    # exact timestamps and CAN tools (a config without ``logging:`` wrote only ASC).
    can_formats: list[Literal["asc", "blf", "csv", "log", "trc"]] = ["asc", "blf"]
    """CAN log formats written (python-can's): ``asc``, ``blf``, ``csv``, ``log``, ``trc``."""
    can_frames: Literal["all", "servos"] = "all"
    """``all``: every frame sent and every frame the adapter delivers (foreign nodes, error
    frames); ``servos``: only the configured servos' frames."""
    rotate_mb: Float | None = Field(50.0, gt=0)
    """Start a new CAN log file after this many MB; null: never."""
    # Every file of a run together stops growing here (the run log said nothing and filled
    # 104 MB in 25 minutes, only the CAN logs rotated); 1 GiB is ~4 h of the built-in sim.
    max_run_mb: Float = Field(1024.0, gt=0)
    """A whole run (every file) stops growing here, in MB (the bridge says so and keeps
    running)."""
    tlog: Bool = True
    """Record the MAVLink traffic in and out as a .tlog."""
    level: Literal["debug", "info", "warning", "error"] = "info"
    """Console and log level: ``debug``, ``info``, ``warning``, ``error``."""


# ------------------------------------------------------------------------------------------ root


class Config(StrictModel):
    """A whole mavservo configuration file."""

    mavlink: MavlinkConfig = MavlinkConfig()
    """The autopilot side."""
    can: CanConfig = CanConfig()
    """The servo side: the CAN buses."""
    servos: list[ServoConfig] = Field(min_length=1)
    """The servos; at least one."""
    channels: list[ChannelConfig] = []
    """Which MAVLink input drives which servo, and how."""
    gimbals: list[GimbalConfig] = []
    """Gimbal devices (MAVLink gimbal protocol v2) made of servos."""
    scheduler: SchedulerConfig = SchedulerConfig()
    """Timing of the dual-loop scheduler."""
    simulation: SimulationConfig = SimulationConfig()
    """The built-in simulation; used only by ``sim`` endpoints."""
    logging: LoggingConfig = LoggingConfig()
    """What a run records."""

    def servo(self, name: str) -> ServoConfig:
        """The servo called ``name`` (KeyError if there is none)."""
        for servo in self.servos:
            if servo.name == name:
                return servo
        raise KeyError(name)

    def bus_of(self, servo: ServoConfig) -> BusConfig:
        """The bus a servo hangs on (the only bus when ``servo.bus`` is omitted)."""
        name = servo.bus if servo.bus is not None else self.can.buses[0].name
        for bus in self.can.buses:
            if bus.name == name:
                return bus
        raise KeyError(name)

    def simulated_settings(self, servo: ServoConfig) -> tuple[dict[str, Any], dict[str, Any]]:
        """(physics, faults) of ``servo``'s simulated device: ``simulation.servos[name]`` or
        its ``default``, and a start position inside its limits unless one is given (the
        bridge's built-in simulation and ``mavservo sim --config`` build the same servo)."""
        tuning = self.simulation.servos.get(servo.name) or self.simulation.servos.get("default")
        physics: dict[str, Any] = dict(tuning.physics) if tuning else {}
        low, high = servo.limits_deg
        physics.setdefault("initial_position_deg", min(high, max(low, 0.0)))
        return physics, dict(tuning.faults) if tuning else {}

    def channel_output_deg(self, channel: ServoOutputChannel | ActuatorChannel) -> AngleRange:
        """A channel's output range, defaulting to its servo's soft limits."""
        return channel.output_deg or self.servo(channel.servo).limits_deg
