"""Other DroneCAN nodes that act as masters on the bridge node's bus: who also sends
ArrayCommand, who also broadcasts SafetyState, who uses the bridge's own node id.

A bus is shared (an autopilot's GNSS, ESCs, another controller), but two masters commanding the
same actuators fight silently, an ArduPilot peripheral obeys the last SafetyState it hears, and
two nodes with one id confuse every tool. Each such sender is reported once, by name, up to
:data:`SENDERS_REPORTED` of them (a source id costs a stranger nothing), and every frame
counted. It is one job with its own state (who was reported, for what), fed by
:class:`.node.BridgeNode` with the frames it receives; apart from the node's own traffic so the
rules can be read, and tested, on their own. Pure: no clock, no I/O.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Set

import can

from . import wire
from .notices import Notices

SENDERS_REPORTED = 8
"""Other nodes reported by name (a second ArrayCommand sender, a SafetyState broadcaster), at
most: a source id costs a stranger nothing, and each report is a WARNING line and a STATUSTEXT;
the senders beyond are counted (``senders_not_reported``) and said once."""


class BusSharingWatch:
    """Reports the other masters of one bus (module docstring)."""

    def __init__(
        self,
        node_id: int,
        actuators: Set[int],
        safety_off: bool,
        reassembler: wire.Reassembler,
        counters: Counter[str],
        notices: Notices,
    ) -> None:
        self.node_id = node_id
        self.actuators = frozenset(actuators)
        """The actuator ids the bridge commands on this bus."""
        self.safety_off = safety_off
        """The bridge broadcasts SAFETY_OFF itself (said when another node's SafetyState
        fights it)."""
        self._reassembler = reassembler
        self._counters = counters
        self._notices = notices
        self.foreign_masters: set[int] = set()
        """Other nodes reported for sending ArrayCommand (see :meth:`command`)."""
        self._masters_of_ours: set[int] = set()
        """Those of them reported for commanding the bridge's actuators (two masters)."""
        self.safety_senders: set[int] = set()
        """Other nodes reported for broadcasting SafetyState (see :meth:`safety`)."""
        self._conflict_noted = False

    def node_status(self, source: int) -> None:
        """A NodeStatus from ``source``: one with the bridge's id is another node's."""
        if source != self.node_id:
            return
        self._counters["node_id_conflict"] += 1
        if not self._conflict_noted:
            self._conflict_noted = True
            self._notices.add(
                f"another DroneCAN node sends NodeStatus with the bridge's node id "
                f"{self.node_id}: give one of them another id"
            )

    def command(self, msg: can.Message, source: int, now: float) -> None:
        """Another node's ArrayCommand: reported once per sender, saying whether it commands
        the bridge's actuators (two masters) or others (a second controller, maybe intended)."""
        self._counters["foreign_commands"] += 1
        if source == self.node_id:
            self._counters["own_id_commands"] += 1
        received = self._reassembler.push(msg, now)
        if received is None or source in self._masters_of_ours:
            return
        theirs = sorted({int(c.actuator_id) for c in received.payload.commands})
        shared = [a for a in theirs if a in self.actuators]
        if source in self.foreign_masters and not shared:
            return  # reported already; a sender that turns to the bridge's actuators is again
        if not self._may_report(source):
            return
        self.foreign_masters.add(source)
        if shared:
            self._masters_of_ours.add(source)
        if source == self.node_id:
            self._notices.add(
                f"another DroneCAN node sends ArrayCommand with the bridge's own node id "
                f"{source} (CAN does not echo the bridge's frames), for actuators "
                f"{', '.join(map(str, theirs))}"
                + (f", the bridge's {', '.join(map(str, shared))}" if shared else "")
                + ": a spoofed or misconfigured sender (counted in own_id_commands)"
            )
        elif shared:
            self._notices.add(
                f"DroneCAN node {source} also sends ArrayCommand for actuators "
                f"{', '.join(map(str, shared))} (the bridge's): two masters command these "
                "servos (an autopilot?); give them one master"
            )
        else:
            self._notices.add(
                f"DroneCAN node {source} also sends ArrayCommand on this bus, for actuators "
                f"{', '.join(map(str, theirs))} (not the bridge's)"
            )

    def safety(self, msg: can.Message, source: int, now: float) -> None:
        """Another node's ``ardupilot.indication.SafetyState``: an ArduPilot peripheral obeys
        the last one it hears, so a flight controller (or a stranger) broadcasting it on this
        bus turns the outputs on or off whatever the bridge's plan; reported once per sender,
        every one counted (``foreign_safety_state``)."""
        self._counters["foreign_safety_state"] += 1
        received = self._reassembler.push(msg, now)
        if received is None or received.dtid != wire.DTID_SAFETY_STATE:
            return
        if source in self.safety_senders or not self._may_report(source):
            return
        self.safety_senders.add(source)
        state = "SAFETY_OFF" if int(received.payload.status) == wire.SAFETY_OFF else "SAFETY_ON"
        who = (
            f"another DroneCAN node sends SafetyState with the bridge's own node id {source}"
            if source == self.node_id
            else f"DroneCAN node {source} also broadcasts SafetyState"
        )
        plan = (
            "the bridge's SAFETY_OFF and its SafetyState fight"
            if self.safety_off
            else "the bridge sends none (safety_state: none)"
        )
        self._notices.add(
            f"{who} ({state}): ArduPilot peripherals obey the last one heard, so their outputs "
            f"follow that node, not the bridge's plan ({plan}); only one node may own the "
            "safety state of the bus (a flight controller's CAN driver sends it every 500 ms)"
        )

    def _may_report(self, source: int) -> bool:
        """True while another sender may still be reported by name (:data:`SENDERS_REPORTED`
        distinct nodes; one already reported always may); beyond, counted and said once."""
        reported = self.foreign_masters | self.safety_senders
        if source in reported or len(reported) < SENDERS_REPORTED:
            return True
        self._counters["senders_not_reported"] += 1
        self._notices.once(
            "senders_not_reported",
            f"more than {SENDERS_REPORTED} other DroneCAN nodes send ArrayCommand or "
            "SafetyState on this bus: the others are counted (senders_not_reported), not "
            "reported one by one (a stranger making up node ids?)",
        )
        return False
