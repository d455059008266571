"""The link plan of a ``mavlink-can`` bus: do its CAN frames fit on the MAVLink link?

A ``mavlink-can`` bus (:mod:`mavservo.transport.tunnel_bus`) carries every frame to the servos
as one CAN_FRAME from the bridge to the autopilot, and every frame on the autopilot's CAN bus
(the servos' replies and the autopilot's own DroneCAN traffic) as one CAN_FRAME back. On a
serial link (``mavlink.url`` a device, ``mavlink.baud``) that is the limit: 8N1 carries
``baud / 10`` bytes a second each way, and ArduPilot drops a forwarded frame silently when its
port has no room (ArduPilot 90700977c5, libraries/AP_CANManager/AP_MAVLinkCAN.cpp l. 315:
``if (HAVE_PAYLOAD_SPACE(chan, CAN_FRAME))``, nothing counted). Measured through ArduPlane SITL
at 57,600 baud: 4 servos x 50 Hz lost 15.6 % of the replies, 2 x 10 Hz fit
(../../docs/mavlink-can.md).

So the plan counts, per direction, the frames per second the bus needs (from each servo's
profile, as the bus-load budget does: :func:`~mavservo.config.budget.servo_traffic_of`), the
bytes each takes (pymavlink's own encoding, :func:`~mavservo.mavlink.tunnel_wire_bytes`), the
keep-alive and its answer, and refuses a plan above :data:`TUNNEL_SHARE` of the link's
capacity, the rest being the autopilot's streams and the bridge's own telemetry. It says what
would fit: fewer servos, lower rates, a faster baud. The radio's budget
(``mavlink.link_budget_bytes_s``) is not touched: ArduPilot never routes CAN_FRAME to the
ground station (:mod:`mavservo.mavlink.can_tunnel`).

One forward per autopilot: ArduPilot keeps one forwarding client and one bus (l. 47-53 and
62-66: a request for another bus moves the forward there), so two ``mavlink-can`` buses of one
bridge would take the forward from each other; refused.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from mavservo.config.budget import bus_nodes, node_flows, servo_traffic_of, servos_on
from mavservo.config.schema import BusConfig, Config
from mavservo.config.semantic import Finding
from mavservo.config.urls import is_serial_url
from mavservo.mavlink import tunnel_wire_bytes
from mavservo.scheduling import ServoTraffic
from mavservo.transport import (
    MAVLINK_CAN,
    TUNNEL_FORWARD_TIMEOUT_S,
    TUNNEL_KEEPALIVE_S,
    TUNNEL_OPTION_BOUNDS,
    filter_key,
)

#: The share of the serial link's capacity (each way) the plan gives CAN frames.
TUNNEL_SHARE = 0.75
#: Bits on the wire per byte (8N1: start, 8 data, stop).
BITS_PER_BYTE = 10
#: Serial rates a flight controller's port is set to (SERIALn_BAUD), for "a faster baud".
STANDARD_BAUDS = (57_600, 115_200, 230_400, 460_800, 921_600, 1_500_000, 2_000_000)
#: Frames per second the autopilot's own nodes put on its CAN bus unless the bus says
#: (``options.foreign_frames_hz``): ~27/s measured on ArduPlane SITL with DroneCAN on.
DEFAULT_FOREIGN_HZ = 30.0


def _out_hz(traffic: ServoTraffic) -> float:
    """CAN frames per second to a servo (commands and polls; start-up frames are transient)."""
    return traffic.command_hz + traffic.request_hz * len(traffic.request_shapes)


def _in_hz(traffic: ServoTraffic) -> float:
    """CAN frames per second from a servo (replies, pushes, a node's heartbeat)."""
    polls = traffic.request_hz * len(traffic.request_shapes)
    return (
        traffic.command_hz * traffic.replies_per_command
        + polls * traffic.replies_per_request
        + traffic.push_hz
        + traffic.heartbeat_hz
    )


@dataclass(frozen=True)
class TunnelPlan:
    """One ``mavlink-can`` bus's load on the MAVLink link, each direction, per second."""

    bus: str
    index: int
    servos: int
    out_hz: float
    """CAN frames to the autopilot (servo frames and the bridge's bus node's)."""
    in_hz: float
    """CAN frames back (the servos' and the autopilot's own)."""
    foreign_hz: float
    servo_out_hz: float
    """Of ``out_hz``, what the servos' rates scale (commands, polls)."""
    servo_in_hz: float
    frame_bytes: int
    out_bytes_s: float
    in_bytes_s: float
    baud: int | None
    """The serial link's baud (None: a network link, not checked)."""

    @property
    def capacity_bytes_s(self) -> float | None:
        return None if self.baud is None else self.baud / BITS_PER_BYTE

    @property
    def allowed_bytes_s(self) -> float | None:
        capacity = self.capacity_bytes_s
        return None if capacity is None else capacity * TUNNEL_SHARE

    @property
    def fits(self) -> bool:
        allowed = self.allowed_bytes_s
        return allowed is None or max(self.out_bytes_s, self.in_bytes_s) <= allowed

    def describe(self) -> str:
        """One paragraph: what the bus needs, of what the link carries."""
        text = (
            f"bus {self.bus!r} (mavlink-can): {self.servos} servo(s) need "
            f"{self.out_hz:,.0f} CAN frames/s to the autopilot and {self.in_hz:,.0f} back "
            f"({self.foreign_hz:g}/s of them the autopilot's own, options.foreign_frames_hz): "
            f"{self.out_bytes_s:,.0f} B/s out and {self.in_bytes_s:,.0f} B/s in on the MAVLink "
            f"link ({self.frame_bytes} B per CAN_FRAME)"
        )
        allowed = self.allowed_bytes_s
        if allowed is None:
            return text + "; a network link: not checked against a baud"
        return text + (
            f"; a {self.baud:,}-baud serial link carries {self.capacity_bytes_s:,.0f} B/s "
            f"each way, {TUNNEL_SHARE:.0%} of it ({allowed:,.0f} B/s) for CAN frames"
        )

    def what_fits(self) -> str:
        """Fewer servos, lower rates, a faster baud: each that would make the plan fit."""
        allowed = self.allowed_bytes_s
        assert allowed is not None and self.baud is not None
        per_frame = self.frame_bytes
        options: list[str] = []
        out_fixed = self.out_bytes_s - self.servo_out_hz * per_frame
        in_fixed = self.in_bytes_s - self.servo_in_hz * per_frame
        room = min(allowed - out_fixed, allowed - in_fixed)
        if self.servos and room > 0:
            per_servo = max(self.servo_out_hz, self.servo_in_hz) * per_frame / self.servos
            count = math.floor(room / per_servo) if per_servo > 0 else self.servos
            if 0 < count < self.servos:
                options.append(f"at most {count} servo(s) at these rates")
            scale = min(
                (allowed - out_fixed) / (self.servo_out_hz * per_frame)
                if self.servo_out_hz
                else math.inf,
                (allowed - in_fixed) / (self.servo_in_hz * per_frame)
                if self.servo_in_hz
                else math.inf,
            )
            if scale < 1:
                options.append(
                    f"the servos' rates lowered to {math.floor(scale * 100)} % "
                    "(a longer scheduler.command_period_s, lower telemetry_hz)"
                )
        need = max(self.out_bytes_s, self.in_bytes_s) / TUNNEL_SHARE * BITS_PER_BYTE
        faster = next((baud for baud in STANDARD_BAUDS if baud >= need), None)
        if faster is not None:
            options.append(f"mavlink.baud {faster:,} (and SERIALn_BAUD on the autopilot)")
        if not options:
            return "nothing at this link's speed: move servos to a USB-CAN adapter"
        return "; or ".join(options)


def tunnel_plans(config: Config) -> list[TunnelPlan]:
    """The plan of every ``mavlink-can`` bus, in config order."""
    return [
        tunnel_plan(config, bus, index)
        for index, bus in enumerate(config.can.buses)
        if bus.interface == MAVLINK_CAN
    ]


def tunnel_plan(config: Config, bus: BusConfig, index: int) -> TunnelPlan:
    timing = config.scheduler
    servos = servos_on(config, bus)
    node, packed = node_flows(bus, servos, timing)
    traffic = [servo_traffic_of(s, timing, packed=s.name in packed) for s in servos]
    servo_out = sum(_out_hz(t) for t in traffic)
    servo_in = sum(_in_hz(t) for t in traffic)
    foreign = float(bus.options.get("foreign_frames_hz", DEFAULT_FOREIGN_HZ))
    keepalive_hz = 1.0 / float(bus.options.get("keepalive_s", TUNNEL_KEEPALIVE_S))
    out_hz = servo_out + sum(flow.rate_hz for flow in node)
    in_hz = servo_in + foreign
    wire = tunnel_wire_bytes(config.mavlink.signing is not None)
    url = config.mavlink.url
    return TunnelPlan(
        bus=bus.name,
        index=index,
        servos=len(servos),
        out_hz=out_hz,
        in_hz=in_hz,
        foreign_hz=foreign,
        servo_out_hz=servo_out,
        servo_in_hz=servo_in,
        frame_bytes=wire.frame,
        out_bytes_s=out_hz * wire.frame + keepalive_hz * wire.request,
        in_bytes_s=in_hz * wire.frame + keepalive_hz * wire.ack,
        baud=config.mavlink.baud if is_serial_url(url) else None,
    )


def tunnel_checks(config: Config) -> list[Finding]:
    """A plan that does not fit its link, and a second ``mavlink-can`` bus, refused."""
    findings: list[Finding] = []
    tunnelled = [i for i, bus in enumerate(config.can.buses) if bus.interface == MAVLINK_CAN]
    for index in tunnelled[1:]:
        findings.append(
            (
                ("can", "buses", index, "interface"),
                "only one mavlink-can bus per autopilot: ArduPilot forwards one CAN bus to one "
                "client (a request for another bus moves the forward); use a USB-CAN adapter "
                "for the other bus",
            )
        )
    for index in tunnelled:
        findings += _option_findings(config.can.buses[index], index)
    if findings:
        return findings
    for plan in tunnel_plans(config):
        if not plan.fits:
            findings.append(
                (
                    ("can", "buses", plan.index),
                    f"{plan.describe()}: does not fit (ArduPilot drops what its port has no "
                    f"room for, silently); would fit: {plan.what_fits()}",
                )
            )
    return findings


def _option_findings(bus: BusConfig, index: int) -> list[Finding]:
    """Options outside :data:`~mavservo.transport.TUNNEL_OPTION_BOUNDS`, and a forward timeout
    not above two keep-alives (one missed answer must not read as a lost forward)."""
    findings: list[Finding] = []
    options = bus.options
    for key, (low, high) in TUNNEL_OPTION_BOUNDS.items():
        value = options.get(key)
        if isinstance(value, int | float) and not low <= value <= high:
            findings.append(
                (("can", "buses", index, "options", key), f"{key} must be in {low:g}..{high:g}")
            )
    keepalive = float(options.get("keepalive_s", TUNNEL_KEEPALIVE_S))
    timeout = float(options.get("forward_timeout_s", TUNNEL_FORWARD_TIMEOUT_S))
    if not findings and timeout <= 2 * keepalive:
        findings.append(
            (
                ("can", "buses", index, "options", "forward_timeout_s"),
                f"forward_timeout_s ({timeout:g}) must exceed two keep-alives "
                f"(2 x keepalive_s = {2 * keepalive:g} s)",
            )
        )
    return findings


def tunnel_plan_lines(config: Config) -> list[str]:
    """``mavservo check``'s lines about the ``mavlink-can`` buses (none without one)."""
    return [
        f"link plan: {plan.describe()}: {'fits' if plan.fits else 'DOES NOT FIT'}"
        for plan in tunnel_plans(config)
    ]


def tunnel_keeps_extended(config: Config, bus: BusConfig) -> bool:
    """Whether a ``mavlink-can`` bus must pass 29-bit frames on: one of its servos answers with
    a 29-bit id, or a bus node (DroneCAN) is configured on it. Otherwise every 29-bit frame is
    the autopilot's own DroneCAN traffic, which the bus drops and counts (``ignored``)."""
    servos = servos_on(config, bus)
    if bus.node or bus_nodes(bus, servos):
        return True
    return any(
        frame.extended and frame.direction == "from_servo"
        for servo in servos
        for frame in servo.make_profile().identifiers()
    )


def tunnel_filter_ids(config: Config, bus: BusConfig) -> list[int] | None:
    """The CAN_FILTER_MODIFY keys (:func:`~mavservo.transport.filter_key`) of every 11-bit id
    a servo of ``bus`` may answer with: the autopilot then forwards those and not its own
    DroneCAN traffic. None when the bus needs 29-bit frames (:func:`tunnel_keeps_extended`):
    their keys would be DroneCAN's own."""
    if tunnel_keeps_extended(config, bus):
        return None
    replies = [
        frame
        for servo in servos_on(config, bus)
        for frame in servo.make_profile().identifiers()
        if frame.direction == "from_servo"
    ]
    keys = {
        filter_key(can_id)
        for can_id in range(0x800)
        for frame in replies
        # the id alone decides the key: a frame's first-byte match does not narrow it
        if not frame.extended and not (can_id ^ frame.arbitration_id) & frame.id_mask & 0x7FF
    }
    return sorted(keys) or None
