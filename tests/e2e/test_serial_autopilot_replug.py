"""The autopilot on a serial link that is unplugged and plugged back: the bridge rides it out.

The autopilot's serial port is a real pty behind a stable symlink (as udev gives a USB serial
adapter a stable /dev/serial/by-id name). Unplugging closes the pty and removes the link; the
bridge must keep running, say so, reopen the port with backoff once it is back, and act on the
autopilot's commands again.
"""

from __future__ import annotations

import contextlib
import os
import select
import tempfile
import threading
import tty
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.app.bridge import Bridge
from mavservo.config import load_config_text
from tests.support.bridge import sim_servo
from tests.support.waiting import wait_until

CONFIG = """
mavlink: {{url: "{path}", baud: 115200, heartbeat_timeout_s: 5.0}}
can: {{buses: [{{name: bus0, interface: aa55, channel: sim}}]}}
servos:
  - {{name: s1, profile: rmd-x, can_id: 1, limits_deg: [-30, 30], telemetry_hz: 10}}
channels:
  - {{servo: s1, source: servo_output, channel: 1, input: {{min: 1100, max: 1900, trim: 1500}},
     output_deg: [-30, 30]}}
"""


class SerialAutopilot:
    """The autopilot's end of a pty: sends MAVLink, collects what the bridge sends back."""

    def __init__(self, link: Path) -> None:
        self.link = link
        self.mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        self.master = -1
        self.slave = -1
        self.received = bytearray()
        self._stop = threading.Event()
        self._reader: threading.Thread | None = None

    def plug(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.master)
        tty.setraw(self.slave)
        tmp = self.link.with_suffix(".new")
        os.symlink(os.ttyname(self.slave), tmp)
        os.replace(tmp, self.link)
        self._stop.clear()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def unplug(self) -> None:
        self._stop.set()
        if self._reader is not None:
            self._reader.join(2.0)
        with contextlib.suppress(FileNotFoundError):
            self.link.unlink()
        for fd in (self.master, self.slave):
            with contextlib.suppress(OSError):
                os.close(fd)

    def _read(self) -> None:
        for _ in range(100_000):  # bounded; each turn waits at most 50 ms
            if self._stop.is_set():
                return
            ready, _, _ = select.select([self.master], [], [], 0.05)
            if ready:
                try:
                    self.received += os.read(self.master, 4096)
                except OSError:
                    return

    def send_state(self, pwm: int) -> None:
        heartbeat = self.mav.heartbeat_encode(1, 3, 0, 0, 4, 3).pack(self.mav)
        outputs = self.mav.servo_output_raw_encode(0, 0, pwm, *([0] * 15)).pack(self.mav)
        os.write(self.master, heartbeat + outputs)

    def heartbeats_from(self, component: int) -> int:
        parser = mavlink2.MAVLink(None)
        parser.robust_parsing = True
        messages = parser.parse_buffer(bytes(self.received)) or []
        return sum(
            1 for m in messages if m.get_type() == "HEARTBEAT" and m.get_srcComponent() == component
        )


def dropped_while_down(bridge: Bridge) -> int:
    """Messages the bridge's MAVLink side had to send while its link was down."""
    assert bridge.mavlink is not None
    return int(bridge.mavlink.stats()["link"].get("send_dropped_link_down", 0))


def test_autopilot_serial_unplug_and_replug() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        link = Path(tmp) / "ttyACM0"
        autopilot = SerialAutopilot(link)
        autopilot.plug()
        config = load_config_text(CONFIG.format(path=link), "serial.yaml")
        bridge = Bridge(config, log_dir=False, status=lambda line: None)
        bridge.start()
        try:
            servo = sim_servo(bridge, "s1")
            assert wait_until(lambda: (autopilot.send_state(1900), servo.position_deg > 29)[1], 8)
            assert wait_until(lambda: autopilot.heartbeats_from(140) >= 1, 3)

            autopilot.unplug()
            assert wait_until(lambda: any("lost" in t for _, t in bridge.events), 5), bridge.events
            # the port is gone and the bridge carries on: its MAVLink side keeps producing
            # heartbeats and telemetry, counted as dropped while there is no link (an event to
            # wait for, not a fixed sleep; a dead tick thread would stop the count)
            dropped = dropped_while_down(bridge)
            assert wait_until(lambda: dropped_while_down(bridge) >= dropped + 5, 5)
            assert bridge.mavlink is not None and bridge.mavlink.is_running

            autopilot.received.clear()
            autopilot.plug()
            assert wait_until(lambda: any("recovered" in t for _, t in bridge.events), 8), (
                bridge.events
            )
            assert wait_until(lambda: (autopilot.send_state(1100), servo.position_deg < -29)[1], 8)
            assert wait_until(lambda: autopilot.heartbeats_from(140) >= 1, 3)
        finally:
            summary = bridge.stop()
            autopilot.unplug()
    link_stats = summary["mavlink"]["link"]
    assert link_stats["link_lost"] == 1 and link_stats["reconnects"] == 1
