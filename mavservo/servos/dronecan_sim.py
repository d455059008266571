"""The simulated DroneCAN actuator node (built-in simulation, ``mavservo sim``), made with the
same ``dronecan`` package as the bridge's side.

It does what a DroneCAN servo does: takes its actuator's entry from every ``ArrayCommand`` on
the bus (reassembling multi-frame transfers, so a bad CRC or a lost frame loses the command as
on a real node), reports ``uavcan.equipment.actuator.Status`` at its status rate (a two-frame
transfer) and ``uavcan.protocol.NodeStatus`` once a second, its health WARNING while the motor
reports a fault. Silencing the simulated servo (``faults: {silent: true}``) silences the node.

A servo with ``options.unique_id`` starts without a node id, as such a node does: it sends only
anonymous ``dynamic_node_id.Allocation`` requests (its unique id in three parts, the next part
as soon as the allocator echoes the previous ones, a new first part every second), ignores
commands, and takes the id the allocator hands out.
"""

from __future__ import annotations

import math
from collections import Counter

import can

from . import dronecan_wire as wire
from .base import NO_FAULT, SimMotor
from .dronecan import DroneCanOptions


class DroneCanDevice:
    """One actuator node on a :class:`SimMotor` (module docstring)."""

    pushes = True

    def __init__(self, motor: SimMotor, node_id: int, options: DroneCanOptions) -> None:
        self.motor = motor
        self.unique_id = bytes.fromhex(options.unique_id) if options.unique_id else None
        self.node_id: int | None = None if self.unique_id else node_id
        self._next_request = -math.inf
        self.options = options
        self.start: float | None = None
        self._next_status = -math.inf
        self._transfer_ids: Counter[int] = Counter()
        self._reassembler = wire.Reassembler()
        self.commands_seen = 0

    def accepts(self, msg: can.Message) -> bool:
        if not wire.is_message_frame(msg) or wire.source_node(msg) in (0, self.node_id):
            return False
        wanted = wire.DTID_ARRAY_COMMAND if self.node_id else wire.DTID_ALLOCATION
        return wire.message_dtid(msg) == wanted

    def handle(self, msg: can.Message, now: float) -> list[can.Message]:
        received = self._reassembler.push(msg, now)
        if received is not None and received.dtid == wire.DTID_ALLOCATION:
            return self._allocation_answer(received.payload)
        if received is None or received.dtid != wire.DTID_ARRAY_COMMAND or not self.node_id:
            return []
        for command in received.payload.commands:
            if int(command.actuator_id) != self.options.actuator_id:
                continue
            angle = self._angle(int(command.command_type), float(command.command_value))
            if angle is not None:
                self.commands_seen += 1
                self.motor.command_position(angle, None, now)
        return []

    def _angle(self, command_type: int, value: float) -> float | None:
        if not math.isfinite(value):
            return None
        if command_type == wire.COMMAND_TYPE_POSITION:
            return math.degrees(value)
        if command_type == wire.COMMAND_TYPE_UNITLESS:
            o = self.options
            value = max(-1.0, min(1.0, value))
            span = o.unitless_max_deg - o.unitless_min_deg
            return o.unitless_min_deg + (value + 1.0) / 2.0 * span
        return None  # force, speed, PWM: not a position servo's business

    def _tid(self, dtid: int) -> int:
        tid = self._transfer_ids[dtid] & 0x1F
        self._transfer_ids[dtid] = tid + 1
        return tid

    def _allocation_request(self, part: bytes, first: bool) -> list[can.Message]:
        assert self.unique_id is not None
        allocation = wire.lib().uavcan.protocol.dynamic_node_id.Allocation()
        allocation.node_id = 0  # no preference
        allocation.first_part_of_unique_id = first
        allocation.unique_id.from_bytes(part)
        discriminator = int.from_bytes(self.unique_id[:2], "little")
        return wire.encode_anonymous(allocation, discriminator, self._tid(wire.DTID_ALLOCATION))

    def _allocation_answer(self, answer: object) -> list[can.Message]:
        """The allocator echoed part of a unique id, or handed out an id."""
        if self.node_id is not None or self.unique_id is None:
            return []
        echoed = bytes(answer.unique_id.to_bytes())  # type: ignore[attr-defined]
        if not echoed or not self.unique_id.startswith(echoed):
            return []  # another node's exchange
        node_id = int(answer.node_id)  # type: ignore[attr-defined]
        if len(echoed) == len(self.unique_id):
            if node_id:
                self.node_id = node_id
            return []
        return self._allocation_request(self.unique_id[len(echoed) : len(echoed) + 6], False)

    def status(self, now: float) -> list[can.Message]:
        if self.node_id is None:
            if now < self._next_request or self.unique_id is None:
                return []
            self._next_request = now + 1.0
            return self._allocation_request(self.unique_id[:6], True)
        if self.start is None:
            self.start = now
        motor = self.motor
        payload = wire.lib().uavcan.equipment.actuator.Status(
            actuator_id=self.options.actuator_id,
            position=math.radians(motor.position_deg),
            force=math.nan,
            speed=math.radians(motor.velocity_dps),
            power_rating_pct=wire.POWER_RATING_UNKNOWN,
        )
        out = wire.encode_message(
            payload, self.node_id, self._tid(wire.DTID_ACTUATOR_STATUS), wire.PRIORITY_MEDIUM
        )
        if now >= self._next_status:
            self._next_status = now + wire.NODE_STATUS_PERIOD_S
            health = wire.HEALTH_OK if motor.active_faults == NO_FAULT else wire.HEALTH_WARNING
            status = wire.node_status(now - self.start, health, wire.MODE_OPERATIONAL)
            out += wire.encode_message(
                status, self.node_id, self._tid(wire.DTID_NODE_STATUS), wire.PRIORITY_LOW
            )
        return out

    def tick(self, now: float) -> None:
        return None
