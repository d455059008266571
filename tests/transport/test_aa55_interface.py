"""The ``aa55`` python-can interface over a real pseudo-terminal; the test plays the adapter."""

from __future__ import annotations

import contextlib
import os
import select
import time
import tty
from collections.abc import Iterator

import can
import pytest

from mavservo.app.bridge import Bridge
from mavservo.config.loader import load_config_text
from mavservo.transport.aa55 import codec as aa55
from mavservo.transport.aa55.bus import (
    AUTO_HOLD_BYTES,
    AUTO_HOLD_S,
    LOAD_WINDOW_S,
    LineLoad,
    auto_hold_s,
)
from mavservo.transport.aa55.codec import Frame
from tests.support.waiting import free_udp_port


class AdapterEnd:
    """The adapter's side of a pty pair: raw bytes in and out, with bounded reads."""

    def __init__(self) -> None:
        self.master, slave = os.openpty()
        tty.setraw(self.master)
        tty.setraw(slave)
        self.path = os.ttyname(slave)
        self._slave = slave  # kept open so the line stays up while the bus reopens it

    def read(self, n: int, timeout: float = 2.0) -> bytes:
        out = b""
        deadline = time.monotonic() + timeout
        while len(out) < n and time.monotonic() < deadline:
            ready, _, _ = select.select([self.master], [], [], deadline - time.monotonic())
            if ready:
                out += os.read(self.master, n - len(out))
        return out

    def write(self, data: bytes) -> None:
        os.write(self.master, data)

    def unplug(self) -> None:
        os.close(self.master)
        os.close(self._slave)


@pytest.fixture
def adapter() -> Iterator[AdapterEnd]:
    end = AdapterEnd()
    yield end
    for fd in (end.master, end._slave):
        with contextlib.suppress(OSError):  # already closed by an unplug test
            os.close(fd)


def test_bus_sends_settings_then_frames(adapter: AdapterEnd) -> None:
    with can.Bus(interface="aa55", channel=adapter.path, bitrate=500_000, mode="normal") as bus:
        assert adapter.read(20) == aa55.settings_frame(500_000)
        msg = can.Message(
            arbitration_id=0x141, data=bytes.fromhex("A400F40128230000"), is_extended_id=False
        )
        bus.send(msg)
        assert adapter.read(13) == aa55.encode(msg)


def test_a_second_opener_of_the_adapter_is_refused_while_the_first_holds_it(
    adapter: AdapterEnd,
) -> None:
    """Two processes on one adapter would each read half of every reply: the port is opened
    exclusively, and the second opener is told who to look for."""
    with (
        can.Bus(interface="aa55", channel=adapter.path),
        pytest.raises(can.CanInitializationError, match="in use by another process"),
    ):
        can.Bus(interface="aa55", channel=adapter.path)
    with can.Bus(interface="aa55", channel=adapter.path):  # free again once the first shut down
        pass


def test_fixed_protocol_is_configured_and_used(adapter: AdapterEnd) -> None:
    with can.Bus(interface="aa55", channel=adapter.path, protocol="fixed") as bus:
        settings = adapter.read(20)
        assert settings[2] == aa55.CMD_SETTINGS_FIXED
        msg = can.Message(arbitration_id=0x2901, data=b"\x01\x02", is_extended_id=True)
        bus.send(msg)
        assert adapter.read(20) == aa55.encode(msg, "fixed")
        adapter.write(aa55.encode(msg, "fixed"))
        got = bus.recv(2.0)
        assert got is not None and got.arbitration_id == 0x2901 and bytes(got.data) == b"\x01\x02"


def test_recv_returns_frames_across_garbage_and_split_writes(adapter: AdapterEnd) -> None:
    sent = [
        Frame(0x240 + i, False, False, 8, bytes([0x9C, i, 0, 0, 0, 0, 0, 0])) for i in range(1, 9)
    ]
    stream = b"\x00\xaa\xaa".join(aa55.encode(f) for f in sent)
    with can.Bus(interface="aa55", channel=adapter.path) as bus:
        adapter.read(20)
        for i in range(0, len(stream), 5):
            adapter.write(stream[i : i + 5])
        got = []
        for _ in range(len(sent) * 3):
            msg = bus.recv(1.0)
            if msg is None:
                break
            got.append(
                Frame(
                    msg.arbitration_id,
                    msg.is_extended_id,
                    msg.is_remote_frame,
                    msg.dlc,
                    bytes(msg.data),
                )
            )
        assert got == sent
        assert bus.stats()["rejected"]["bad_type"] == 2 * (len(sent) - 1)  # two false 0xAA per gap


def test_recv_timeout_is_honoured_and_zero_does_not_block(adapter: AdapterEnd) -> None:
    with can.Bus(interface="aa55", channel=adapter.path) as bus:
        adapter.read(20)
        assert bus.recv(0) is None
        t0 = time.monotonic()
        assert bus.recv(0.05) is None
        assert time.monotonic() - t0 >= 0.05


def test_partial_frame_then_idle_is_not_an_error(adapter: AdapterEnd) -> None:
    """python-can issue #2024: seeedstudio raises TypeError when a read times out mid-frame."""
    frame = aa55.encode(Frame(0x123, False, False, 8, bytes(8)))
    with can.Bus(interface="aa55", channel=adapter.path) as bus:
        adapter.read(20)
        adapter.write(frame[:6])
        assert bus.recv(0.05) is None
        adapter.write(frame[6:])  # the rest arrives late: a truncated candidate, then garbage
        bus.recv(0.05)
        good = aa55.encode(Frame(0x124, False, False, 1, b"\x01"))
        adapter.write(good)
        msg = bus.recv(1.0)
        assert msg is not None and msg.arbitration_id == 0x124


def test_software_filters_apply_and_single_filter_goes_to_hardware(adapter: AdapterEnd) -> None:
    filters = [{"can_id": 0x241, "can_mask": 0x7FF, "extended": False}]
    with can.Bus(interface="aa55", channel=adapter.path, can_filters=filters) as bus:
        settings = adapter.read(20)
        assert int.from_bytes(settings[5:9], "little") == 0x241
        assert int.from_bytes(settings[9:13], "little") == 0x7FF
        adapter.write(
            aa55.encode(Frame(0x242, False, False, 0, b""))
            + aa55.encode(Frame(0x241, False, False, 0, b""))
        )
        msg = bus.recv(1.0)
        assert msg is not None and msg.arbitration_id == 0x241


def test_unplugged_adapter_raises_can_operation_error(adapter: AdapterEnd) -> None:
    bus = can.Bus(interface="aa55", channel=adapter.path)
    try:
        adapter.read(20)
        adapter.unplug()
        with pytest.raises(can.CanOperationError, match="gone"):
            for _ in range(3):  # bounded: the first read after the hang-up must fail
                bus.recv(0.2)
    finally:
        bus.shutdown()


def test_bad_arguments_are_initialisation_errors(adapter: AdapterEnd) -> None:
    with pytest.raises(can.CanInitializationError, match="bitrate 12345"):
        can.Bus(interface="aa55", channel=adapter.path, bitrate=12345)
    with pytest.raises(can.CanInitializationError, match="cannot open"):
        can.Bus(interface="aa55", channel="/dev/does-not-exist")


def test_send_of_impossible_frame_is_a_clear_error(adapter: AdapterEnd) -> None:
    with can.Bus(interface="aa55", channel=adapter.path) as bus:
        bad = can.Message(arbitration_id=0x800, is_extended_id=False, check=False)
        with pytest.raises(can.CanOperationError, match="out of range"):
            bus.send(bad)


def test_half_frame_completed_while_the_caller_was_away_is_not_lost(adapter: AdapterEnd) -> None:
    """A slow caller must not turn a frame split across reads into a 'truncated' rejection."""
    frame = aa55.encode(Frame(0x141, False, False, 8, bytes(range(8))))
    with can.Bus(interface="aa55", channel=adapter.path) as bus:
        adapter.read(20)
        adapter.write(frame[:6])
        assert bus.recv(0.001) is None  # reads the first half
        adapter.write(frame[6:])
        time.sleep(0.02)  # longer than the idle flush: the rest is already in the port
        msg = bus.recv(1.0)
        assert msg is not None and msg.arbitration_id == 0x141
        assert bus.stats()["rejected"] == {}


def test_received_messages_are_plain_messages_and_control_frames_are_not_queued(
    adapter: AdapterEnd,
) -> None:
    """The decoder builds the bus's ``can.Message``s itself; a status reply from the adapter
    between data frames is recognised and dropped, and the frames around it still arrive."""
    status = bytearray(20)
    status[0:3] = bytes((0xAA, 0x55, aa55.CMD_STATUS))
    status[19] = sum(status[2:19]) & 0xFF
    first = Frame(0x241, False, False, 8, bytes(range(8)))
    second = Frame(0x1ABCDE, True, True, 3, b"")
    with can.Bus(interface="aa55", channel=adapter.path) as bus:
        adapter.read(20)
        adapter.write(aa55.encode(first) + bytes(status) + aa55.encode(second))
        got = [bus.recv(1.0) for _ in range(2)]
        assert bus.recv(0.05) is None
    for msg, frame in zip(got, (first, second), strict=True):
        assert type(msg) is can.Message
        assert (msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame, msg.dlc) == (
            frame.arbitration_id,
            frame.is_extended_id,
            frame.is_remote_frame,
            frame.dlc,
        )
        assert type(msg.data) is bytearray and bytes(msg.data) == frame.data
        assert msg.channel == adapter.path and msg.is_rx and not msg.is_error_frame
        assert msg.timestamp > 0
    assert bus.stats()["control_frames"] == 1


def test_a_filtered_out_message_does_not_end_the_wait(adapter: AdapterEnd) -> None:
    """Two software filters (none goes to the hardware): a frame they drop is read and skipped,
    and ``recv(timeout)`` goes on waiting for one that passes, until its deadline."""
    filters = [{"can_id": 0x241, "can_mask": 0x7FF}, {"can_id": 0x242, "can_mask": 0x7FF}]
    with can.Bus(interface="aa55", channel=adapter.path, can_filters=filters) as bus:
        adapter.read(20)
        adapter.write(aa55.encode(Frame(0x300, False, False, 0, b"")))
        t0 = time.monotonic()
        assert bus.recv(0.1) is None
        assert time.monotonic() - t0 >= 0.1
        adapter.write(
            aa55.encode(Frame(0x300, False, False, 0, b""))
            + aa55.encode(Frame(0x242, False, False, 0, b""))
        )
        msg = bus.recv(1.0)
        assert msg is not None and msg.arbitration_id == 0x242
        assert bus.stats()["frames"] == 3


def test_read_interval_keeps_the_bus_away_from_the_port_that_long(adapter: AdapterEnd) -> None:
    """With ``read_interval_s`` the next read comes that long after the last one, even when
    bytes are already waiting (so bursts gather); the read's time stamps its frames."""
    frames = [aa55.encode(Frame(0x240 + i, False, False, 2, bytes((i, i)))) for i in range(2)]
    with can.Bus(interface="aa55", channel=adapter.path, read_interval_s=0.05) as bus:
        adapter.read(20)
        adapter.write(frames[0])
        first = bus.recv(1.0)
        adapter.write(frames[1])  # waiting in the port before the bus looks again
        second = bus.recv(1.0)
    assert first is not None and second is not None
    assert [first.arbitration_id, second.arbitration_id] == [0x240, 0x241]
    assert second.timestamp - first.timestamp >= 0.05 - 0.002  # wall vs monotonic clock slack


def test_read_interval_keeps_timeouts_and_device_errors(adapter: AdapterEnd) -> None:
    with can.Bus(interface="aa55", channel=adapter.path, read_interval_s=0.05) as bus:
        adapter.read(20)
        adapter.write(aa55.encode(Frame(0x100, False, False, 0, b"")))
        assert bus.recv(1.0) is not None
        assert bus.recv(0) is None  # inside the interval: still does not block
        t0 = time.monotonic()
        assert bus.recv(0.08) is None
        assert time.monotonic() - t0 >= 0.08
        adapter.unplug()
        with pytest.raises(can.CanOperationError, match="gone"):
            for _ in range(3):  # bounded: the first read after the hang-up must fail
                bus.recv(0.2)
    with pytest.raises(can.CanInitializationError, match="read_interval_s"):
        can.Bus(interface="aa55", channel=adapter.path, read_interval_s=1.0)
    for bad in ("fast", "nan", -0.001):
        with pytest.raises(can.CanInitializationError, match="read_interval_s"):
            can.Bus(interface="aa55", channel=adapter.path, read_interval_s=bad)


def test_read_interval_from_a_config_file_string(adapter: AdapterEnd) -> None:
    with can.Bus(interface="aa55", channel=adapter.path, read_interval_s="0.004") as bus:
        assert bus.stats()["read_interval_s"] == 0.004


def test_line_load_follows_the_byte_rate_and_forgets_a_silence() -> None:
    load = LineLoad(0.05)
    rate = 0.0
    for k in range(500):  # 200 bytes every ms: 200,000 bytes/s
        rate = load.add(200, k * 0.001)
    assert rate == pytest.approx(200_000, rel=0.02)
    assert load.add(13, 0.499 + 0.25) < 0.01 * 200_000  # after 5 windows of silence


def test_auto_hold_waits_only_on_a_busy_line_and_never_lets_too_much_gather() -> None:
    busy = 50_000.0  # a quarter of 2 Mbaud, bytes/s
    assert auto_hold_s(20_000.0, 26, busy) == 0.0  # servo traffic: every burst at once
    assert auto_hold_s(200_000.0, 200, busy) == AUTO_HOLD_S  # saturated 2 Mbaud line
    assert auto_hold_s(1_000_000.0, 1000, busy) == pytest.approx(AUTO_HOLD_BYTES / 1e6)
    assert auto_hold_s(1_000_000.0, AUTO_HOLD_BYTES, busy) == 0.0  # behind: read again now
    for rate in (60_000.0, 200_000.0, 1e6, 1e8):  # a hold never lets more than the budget in
        assert rate * auto_hold_s(rate, 100, busy) <= AUTO_HOLD_BYTES + 1e-6


def test_auto_read_interval_holds_only_while_the_line_is_busy(adapter: AdapterEnd) -> None:
    """Default ``"auto"``: reads follow every burst on a quiet line; on a line carrying more
    than a quarter of 2 Mbaud they are spaced by AUTO_HOLD_S; quiet again, at once again."""
    frame = aa55.encode(Frame(0x241, False, False, 8, bytes(8)))
    burst = frame * 150  # ~2 KB every 10 ms: ~195,000 bytes/s, near a saturated line
    with can.Bus(interface="aa55", channel=adapter.path) as bus:
        adapter.read(20)
        assert bus.read_interval_s == "auto"
        adapter.write(frame)
        assert bus.recv(1.0) is not None
        assert bus.stats()["read_interval_s"] == 0.0  # one frame: quiet
        holds = set()
        got = 0
        for _ in range(20):  # bounded: 20 bursts, each drained before the next
            adapter.write(burst)
            for _ in range(150):
                if bus.recv(1.0) is None:
                    break
                got += 1
            holds.add(bus.stats()["read_interval_s"])
            time.sleep(0.01)
        assert got == 20 * 150  # nothing lost while holding
        assert max(holds) > 0.0 and max(holds) <= AUTO_HOLD_S
        adapter.write(frame * 300)  # 3,900 bytes at once: more than a hold may let gather
        assert bus.recv(1.0) is not None
        assert bus.stats()["read_interval_s"] == 0.0  # behind: the next read follows at once
        for _ in range(299):  # bounded: drain the block
            assert bus.recv(1.0) is not None
        time.sleep(5 * LOAD_WINDOW_S)
        adapter.write(frame)
        assert bus.recv(1.0) is not None
        assert bus.stats()["read_interval_s"] == 0.0


def test_the_bridge_passes_the_configured_read_interval_to_its_adapter() -> None:
    port = free_udp_port()
    config = load_config_text(f"""
mavlink: {{url: "udpin:127.0.0.1:{port}", system_id: 1}}
can:
  buses: [{{name: bus0, channel: sim, read_interval_s: 0.004}}]
servos:
  - {{name: s1, profile: rmd-x, can_id: 1}}
""")
    bridge = Bridge(config, log_dir=False, status=lambda line: None)
    bridge.start()
    try:
        inner = bridge.buses["bus0"].inner
        assert inner is not None and inner.read_interval_s == 0.004
    finally:
        bridge.stop()
    default = load_config_text("servos: [{name: s1, profile: rmd-x, can_id: 1}]")
    assert default.can.buses[0].read_interval_s == "auto"
