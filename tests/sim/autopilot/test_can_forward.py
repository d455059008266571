"""The simulated autopilot's CAN forward behaves as ArduPilot's AP_MAVLinkCAN (90700977c5):
bus numbering, the 5 s keep-alive checked every 100 frames, the 20-frame buffer, the port's
room, the DroneCAN-shaped filter. Pure: times and the bus are handed in."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from mavservo.sim.autopilot.can_forward import (
    BUFFER_FRAMES,
    CAN_FILTER_ADD,
    CAN_FILTER_REPLACE,
    CanForwarder,
    SerialRoom,
    dronecan_filter_id,
)

REQUESTER = (1, 140)


def forwarder(**kwargs):
    written: list[tuple[int, int, bytes]] = []
    state = {"bus_free": True}

    def write(bus: int, raw_id: int, data: bytes, fd: bool) -> bool:
        if not state["bus_free"]:
            return False
        written.append((bus, raw_id, data))
        return True

    kwargs.setdefault("configured", (0, 1))
    return CanForwarder(write=write, **kwargs), written, state


def test_bus_is_1_based_in_the_command_and_0_based_in_frames() -> None:
    fwd, written, _ = forwarder()
    assert fwd.handle_can_forward(2.0, REQUESTER, 0)
    assert fwd.callback_bus == 1
    out = fwd.can_frame_callback(1, 0x241, b"\x01", False, 10)
    assert out is not None and out.bus == 1 and out.target == REQUESTER
    assert fwd.can_frame_callback(0, 0x241, b"\x01", False, 10) is None  # not the forwarded bus
    fwd.handle_can_frame(0, 2, 0x141, b"\xa4\x00\xff", False)
    assert written == [(0, 0x141, b"\xa4\x00")]  # len bytes only, on bus index 0


def test_stop_unknown_bus_and_moving_the_forward() -> None:
    fwd, _, _ = forwarder(configured=(0,))
    assert not fwd.handle_can_forward(2.0, REQUESTER, 0)  # CAN2 not configured: FAILED
    assert not fwd.handle_can_forward(-3.0, REQUESTER, 0)
    assert fwd.handle_can_forward(1.0, REQUESTER, 0) and fwd.forwarding
    assert fwd.handle_can_forward(0.0, REQUESTER, 0) and not fwd.forwarding  # 0 stops


def test_forward_stops_at_the_100_frame_check_5_s_after_the_last_request() -> None:
    fwd, _, _ = forwarder()
    fwd.handle_can_forward(1.0, REQUESTER, 0)
    sent = [fwd.can_frame_callback(0, 0x241, b"", False, 1000 + i) for i in range(150)]
    assert all(sent)  # within 5 s: the checks at frame 100 pass
    late = [fwd.can_frame_callback(0, 0x241, b"", False, 7000) for _ in range(200)]
    forwarded = sum(1 for out in late if out is not None)
    # ``frame_counter++ == 100`` checks the 101st frame, then every 101st: frame 101 passed
    # (reset to 0), frame 202, the 52nd late one, stops the forward; 51 went out
    assert forwarded == 51
    assert not fwd.forwarding and fwd.counters["forward_expired"] == 1
    # asked again, it forwards again; the counter was left at 101 (uint8): next check at 100
    # after wrapping, 255 frames later
    fwd.handle_can_forward(1.0, REQUESTER, 7000)
    again = [fwd.can_frame_callback(0, 0x241, b"", False, 20_000) for _ in range(300)]
    assert sum(1 for out in again if out is not None) == 255


def test_the_20_frame_buffer_drops_and_counts_when_the_bus_is_full() -> None:
    fwd, written, state = forwarder()
    state["bus_free"] = False
    for i in range(BUFFER_FRAMES + 5):
        fwd.handle_can_frame(0, 1, 0x141, bytes([i]), False)
    assert fwd.counters["buffer_full"] == 5 and written == []
    state["bus_free"] = True
    fwd.process_frame_buffer()
    assert [data for _, _, data in written] == [bytes([i]) for i in range(BUFFER_FRAMES)]


def test_a_frame_without_room_on_the_port_is_dropped_silently_but_counted() -> None:
    room = iter([True, False, True])
    fwd, _, _ = forwarder(room=lambda nbytes: next(room))
    fwd.handle_can_forward(1.0, REQUESTER, 0)
    out = [fwd.can_frame_callback(0, 0x241, b"", False, 1) for _ in range(3)]
    assert [o is not None for o in out] == [True, False, True]
    assert fwd.counters["no_room"] == 1


def test_serial_room_drains_at_the_baud_rate() -> None:
    now = [0.0]
    room = SerialRoom(57_600, lambda: now[0], buffer_bytes=100)
    assert [room(28) for _ in range(4)] == [True, True, True, False]  # 84 queued, 112 > 100
    now[0] += 28 / 5760  # one frame's time at 5,760 B/s
    assert room(28) and not room(28)
    assert SerialRoom(None, lambda: 0.0)(10_000)


def test_filter_keys_on_dronecan_ids_so_11_bit_replies_need_their_top_bits() -> None:
    fwd, _, _ = forwarder()
    fwd.handle_can_forward(1.0, REQUESTER, 0)
    node_status = 0x1015501 | (1 << 31)  # priority 16, NodeStatus (341), node 1
    fwd.handle_can_filter_modify(1, CAN_FILTER_REPLACE, [341])
    assert fwd.can_frame_callback(0, node_status, b"", False, 1) is not None
    assert fwd.can_frame_callback(0, 0x241, b"", False, 1) is None  # RMD-X reply: key 2
    fwd.handle_can_filter_modify(1, CAN_FILTER_ADD, [2])
    assert fwd.can_frame_callback(0, 0x241, b"", False, 1) is not None
    assert fwd.counters["filtered"] == 1


@given(st.integers(0, 0x7FF))
def test_an_11_bit_id_has_a_filter_key_0_to_7(can_id: int) -> None:
    key = dronecan_filter_id(can_id)
    assert 0 <= key <= 7
    assert key == (0 if can_id & 0xFF == 0 or can_id & 0x80 else can_id >> 8)
