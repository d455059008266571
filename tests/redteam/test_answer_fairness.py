"""Answers to requests are shared fairly between requesters, also across ticks and table churn.

Red team (review3) of issue 32 finding 3's answer queue. Before: at every call of ``due`` the
first requester ever queued was asked first, and the budget admits about one answer a tick, so
a stranger that asked first and kept asking (a 200/s PARAM_REQUEST_READ flood over UDP) took
every admitted answer: a ground station's 10 reads got 0 answers within a second each (now 10
of 10, 0.13-0.46 s). And when the table of requesters was full the oldest was forgotten with
its answers: new spoofed requesters pushed the ground station's queued answers out.
"""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.mavlink.answers import MAX_REQUESTERS, AnswerQueue

ROGUE, GCS = (66, 190), (255, 190)


def _value(name: bytes) -> mavlink2.MAVLink_param_value_message:
    return mavlink2.MAVLink_param_value_message(name, 1.0, 9, 90, 0)


def _one_per_call() -> tuple[list[int], object]:
    """An ``admit`` that lets one answer through per call of ``due`` (a tight budget)."""
    calls = [0]

    def admit(_cid: int, _msg: object) -> bool:
        calls[0] += 1
        return calls[0] % 2 == 1  # the first of each call goes, the next waits

    return calls, admit


def test_a_flooding_first_requester_does_not_starve_a_later_one() -> None:
    queue = AnswerQueue()
    queue.put(ROGUE, [(140, _value(b"SRV1_TRIM"))] * 200, 0.0)
    queue.put(GCS, [(140, _value(b"SRV1_MAX"))], 0.0)
    _, admit = _one_per_call()
    served = []
    now = 0.0
    for _ in range(4):  # four ticks
        now += 0.01
        served += [answer.to for answer in queue.due(now, admit)]
    assert GCS in served, served


def test_new_spoofed_requesters_do_not_push_out_a_waiting_ground_station() -> None:
    queue = AnswerQueue()
    queue.put(GCS, [(140, _value(b"SRV1_MAX"))], 0.0)
    for n in range(MAX_REQUESTERS * 4):  # spoofed ids, one read each
        queue.put((100 + n, 190), [(140, _value(b"SRV1_TRIM"))], 0.0)
    served = [answer.to for answer in queue.due(1.0, lambda _c, _m: True)]
    assert GCS in served


def test_over_udp_a_ground_station_reads_parameters_through_a_strangers_read_flood() -> None:
    import os
    import threading
    import time

    from mavservo.app.bridge import Bridge
    from mavservo.config.loader import load_config_text
    from tests.redteam.test_stranger_message_rates import _config, _peer
    from tests.support.waiting import free_udp_port

    os.environ.setdefault("MAVLINK20", "1")
    port = free_udp_port()
    bridge = Bridge(load_config_text(_config(port)), log_dir=False).start()

    rogue = _peer(port, ROGUE)
    time.sleep(0.3)  # the stranger asks first
    gcs = _peer(port, GCS)
    stop = threading.Event()

    def flood() -> None:
        for _ in range(2000):  # bounded: at most 10 s at 200/s
            if stop.wait(0.005):
                return
            rogue.mav.param_request_read_send(1, 140, b"SRV1_TRIM", -1)

    flooder = threading.Thread(target=flood)
    answered = 0
    try:
        flooder.start()
        time.sleep(0.5)
        for _ in range(5):
            gcs.mav.param_request_read_send(1, 140, b"SRV1_MAX", -1)
            for _ in range(20):  # at most 1 s for the answer
                msg = gcs.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.05)
                if msg is not None:
                    answered += 1
                    break
    finally:
        stop.set()
        flooder.join()
        rogue.close()
        gcs.close()
        bridge.stop()
    assert answered >= 4
