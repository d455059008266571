"""A stranger's flood of requests cannot push a ground station's COMMAND_ACKs out.

Red team (review3), real UDP sockets on 127.0.0.1, the default policy (anyone may command).
Before: each response to a command went at once to every peer as an event; a stranger asking
COMPONENT_METADATA (MAV_CMD_REQUEST_MESSAGE 397) 1,000 times a second filled the held events
(256) with its ACKs and answers: 11,654 events dropped in 7 s, and the ground station got 1 of
30 ACKs of its DO_SET_SERVO (all 30 were applied). Now an unverified sender's responses wait in
its own queue and go to it only, in turn with the other requesters: 30 of 30.
"""

from __future__ import annotations

import os
import threading
import time
from typing import Any

from mavservo.app.bridge import Bridge
from mavservo.config.loader import load_config_text
from tests.redteam.test_stranger_message_rates import _config, _peer
from tests.support.waiting import free_udp_port

os.environ.setdefault("MAVLINK20", "1")

DO_SET_SERVO = 183
REQUEST_MESSAGE = 512
COMPONENT_METADATA = 397


def _acks_through(flood_one: Any) -> int:
    """ACKs of 10 DO_SET_SERVO a ground station gets (1 s each) while ``flood_one(conn, n)``
    sends the stranger's n-th message about 1,000 times a second."""
    port = free_udp_port()
    bridge = Bridge(load_config_text(_config(port)), log_dir=False).start()
    rogue = _peer(port, (66, 190))
    gcs = _peer(port, (255, 190))
    stop = threading.Event()

    def flood() -> None:
        for n in range(20_000):  # bounded: at most 10 s
            if stop.is_set():
                return
            flood_one(rogue, n)
            if n % 5 == 4:
                time.sleep(0.0025)  # about 1,000 requests a second, on a loaded machine less

    flooder = threading.Thread(target=flood)
    acked = 0
    try:
        time.sleep(0.5)
        flooder.start()
        time.sleep(1.0)  # the flood has filled whatever it can
        for n in range(10):
            gcs.mav.command_long_send(1, 140, DO_SET_SERVO, 0, 1, 1500 + n, 0, 0, 0, 0, 0)
            for _ in range(20):  # at most 1 s for the ACK
                msg = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.05)
                if msg is not None and msg.command == DO_SET_SERVO:
                    acked += 1
                    break
    finally:
        stop.set()
        flooder.join()
        rogue.close()
        gcs.close()
        bridge.stop()
    return acked


def test_a_ground_stations_acks_get_through_a_strangers_request_flood() -> None:
    def request(conn: Any, _n: int) -> None:
        conn.mav.command_long_send(1, 140, REQUEST_MESSAGE, 0, COMPONENT_METADATA, *[0] * 6)

    assert _acks_through(request) >= 9


def test_acks_do_not_wait_behind_parameter_lists_of_spoofed_senders() -> None:
    """Guards the fix above: the responses, queued per sender, must not wait behind the
    answers of 250 spoofed senders' PARAM_REQUEST_LIST (a first version did: 3 of 30)."""

    def parameter_list(conn: Any, n: int) -> None:
        conn.mav.srcSystem = 2 + n % 250
        conn.mav.param_request_list_send(1, 0)

    assert _acks_through(parameter_list) >= 9
