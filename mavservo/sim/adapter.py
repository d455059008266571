"""The USB-CAN adapter emulator: an AA-55 device on a pseudo-terminal, in front of a simulated bus.

It behaves like the Waveshare / Seeed adapter on the port it publishes: it obeys the settings
frame (bitrate, variable or fixed protocol, mode, filter and mask), decodes AA-55 from the host
with the project's codec, carries the frames over :class:`~mavservo.sim.canbus.SimCanBus` to the
simulated servos, and writes their replies back in AA-55. Any AA-55 client works against it,
python-can's own ``seeedstudio`` interface included.

The port, hot-plug and line corruption are :class:`~mavservo.sim.pty_adapter.PtyAdapter`'s,
shared with the simulated slcan adapter.

Modes follow a CAN controller's: ``normal``; ``loopback`` (frames from the host are echoed back
to it and still transmitted, bus traffic is not received); ``silent`` (listen only: nothing is
transmitted); ``loopback_silent`` (echo only). The filter accepts a received frame when
``(id ^ filter_id) & mask == 0`` (mask 0: everything).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from typing import Any

import can

from mavservo.transport import (
    AA55_MODES,
    AA55Decoder,
    AA55Frame,
    AA55Protocol,
    AA55Settings,
    encode_aa55,
)

from .pty_adapter import DIRECTIONS, LagMeter, LineCorrupter, LineFaults, PtyAdapter
from .servo import SimServo

__all__ = [
    "DIRECTIONS",
    "AdapterEmulator",
    "LagMeter",
    "LineCorrupter",
    "LineFaults",
    "host_decoder",
]

_IDLE_FLUSH_S = 0.005
"""Line idle this long with a partial candidate pending: it was a false start or truncated."""


def host_decoder(protocol: AA55Protocol) -> AA55Decoder:
    """The decoder for the host's bytes, as an adapter's firmware would read them.

    First structurally valid candidate wins, and nothing waits for the byte after a frame
    (``resolve_overlaps=False``): a firmware parser sends each frame out as soon as it is whole,
    and the host's side of the line is clean apart from injected faults.
    """
    return AA55Decoder(protocol, resolve_overlaps=False)


class AdapterEmulator(PtyAdapter):
    """An AA-55 USB-CAN adapter on a pty, carrying frames to simulated servos.

    ``path`` is what a host opens (the stable symlink). Until the host sends a settings frame
    the adapter runs with the constructor's ``bitrate`` and ``protocol``, as a real one keeps
    its last configuration.
    """

    thread_name = "sim-usbcan-adapter"

    def __init__(
        self,
        servos: Iterable[SimServo],
        *,
        bitrate: int = 1_000_000,
        protocol: AA55Protocol = "variable",
        line_faults: LineFaults | None = None,
        link_path: str | None = None,
        seed: int = 0,
        clock: Callable[[], float] = time.monotonic,
        nodes_bitrate: int | None = None,
    ) -> None:
        self.decoder = host_decoder(protocol)
        self.protocol: AA55Protocol = protocol
        self.mode = "normal"
        self.filter_id = 0
        self.mask = 0
        self.settings: AA55Settings | None = None
        self.frames_filtered = 0
        self.settings_received = 0
        super().__init__(
            servos,
            bitrate=bitrate,
            line_faults=line_faults,
            link_path=link_path,
            seed=seed,
            clock=clock,
            nodes_bitrate=nodes_bitrate,
        )

    def _on_plug(self) -> None:
        self.decoder = host_decoder(self.protocol)

    def _on_idle(self, now: float, idle_s: float) -> None:
        if self.decoder.pending and idle_s > _IDLE_FLUSH_S:
            self._handle_items(self.decoder.flush(), now)

    def _from_host(self, data: bytes, now: float) -> None:
        data = self._line_to_adapter(data)
        self._handle_items(self.decoder.feed(data, now), now, data)

    def _handle_items(self, items: list[Any], now: float, chunk: bytes = b"") -> None:
        for item in items:
            if isinstance(item, AA55Settings):
                switched = item.protocol != self.protocol
                self._apply_settings(item)
                if switched:
                    # The rest of this chunk was decoded in the old protocol: decode it again
                    # in the new one (a host sends its first frame right after the settings).
                    at = chunk.find(item.raw)
                    self.decoder = host_decoder(self.protocol)
                    if at >= 0:
                        rest = chunk[at + len(item.raw) :]
                        self._handle_items(self.decoder.feed(rest, now), now, rest)
                    return
            elif isinstance(item, AA55Frame):
                self.frames_from_host += 1
                msg = item.to_message(is_rx=False)
                if self.mode in ("loopback", "loopback_silent"):
                    self._write_frame(msg)
                if self.mode in ("normal", "loopback"):
                    self.canbus.submit(msg, now)
            # other control frames (status requests) get no answer, as on many clones

    def _apply_settings(self, settings: AA55Settings) -> None:
        self.settings = settings
        self.settings_received += 1
        if settings.bitrate is not None:
            self.canbus.bitrate = settings.bitrate
        self.mode = settings.mode if settings.mode in AA55_MODES else "normal"
        self.filter_id = settings.filter_id
        self.mask = settings.mask
        self.protocol = settings.protocol

    def _to_host(self, frames: list[tuple[float, can.Message]]) -> None:
        """Frames that finished on the bus, through the filter, in one write (a USB packet
        train). A flood repeats one message object: it is filtered and encoded once."""
        if self.mode in ("loopback", "loopback_silent"):
            return  # a controller in loopback mode ignores its RX pin
        chunks: list[bytes] = []
        last: can.Message | None = None
        encoded: bytes | None = None
        for _, msg in frames:
            if msg is not last:
                last = msg
                passes = not (msg.arbitration_id ^ self.filter_id) & self.mask
                encoded = encode_aa55(msg, self.protocol) if passes else None
            if encoded is None:
                self.frames_filtered += 1
            else:
                chunks.append(encoded)
        if chunks:
            self._write(b"".join(chunks), len(chunks))

    def _write_frame(self, msg: can.Message) -> None:
        self._write(encode_aa55(msg, self.protocol), 1)
