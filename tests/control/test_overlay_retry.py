"""A parameter save that failed is tried again: the values survive once the disk lets them.

Red team (review3) of issue 32 item 6's saver. Before: the values of a failed write were
dropped from the saver; unless another PARAM_SET came, they were never written, even once the
state directory appeared (mounted late) or the disk had room again, and were lost at the next
restart. Now the saver tries again every interval until a write succeeds.
"""

from __future__ import annotations

import time
from pathlib import Path

from mavservo.config.overlay import read_overlay
from mavservo.control.overlay_saver import OverlaySaver


def test_a_failed_save_is_written_once_the_directory_is_there(tmp_path: Path) -> None:
    state = tmp_path / "state"  # not there yet: the write fails (FileNotFoundError)
    texts: list[str] = []
    saver = OverlaySaver(
        state / "sim.params.yaml", "sim.yaml", on_failure=texts.append, interval_s=0.05
    )
    saver.start()
    try:
        saver.submit({"SRV1_MAX": 20.0})
        for _ in range(100):  # bounded: 5 s
            if saver.failures:
                break
            time.sleep(0.05)
        assert saver.failures >= 1 and texts and "not saved" in texts[0]
        state.mkdir()
        for _ in range(100):  # bounded: 5 s
            if saver.writes:
                break
            time.sleep(0.05)
        assert saver.writes == 1
        assert read_overlay(state / "sim.params.yaml") == {"SRV1_MAX": 20.0}
    finally:
        saver.stop()
