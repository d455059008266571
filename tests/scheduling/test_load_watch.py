"""The measured-load warning (``mavservo.scheduling.load_watch``) on fake time: whose traffic
it is, once per time the bus goes over ``max_load``, again after a minute while it stays."""

from __future__ import annotations

from mavservo.scheduling.load_watch import WARN_AGAIN_S, LoadWatch


def test_the_warning_names_each_partys_share_and_comes_once_per_episode() -> None:
    watch = LoadWatch("bus0", 1_000_000, 1.0, 0.35)
    for step in range(10):  # in one second: servos 100 kbit, others 300 kbit
        t = step * 0.1
        watch.received(t, 10_000, True)
        watch.received(t, 30_000, False)
    text = watch.check(0.95, 0.45)  # the total counts the bridge's own 50 kbit too
    assert text is not None
    assert "measured load 45.0% is over max_load 35%" in text
    assert "the bridge's own frames 5.0%, its servos' 10.0%, other nodes' 30.0%" in text
    assert text.endswith("most is other nodes' traffic")
    assert watch.check(2.0, 0.45) is None  # still over: not again within the minute
    assert watch.check(2.0 + WARN_AGAIN_S, 0.45) is not None
    assert watch.check(70.0, 0.2) is None  # under: the next time over is a new episode
    assert watch.check(71.0, 0.4) is not None
    assert watch.warnings == 3
