"""The one rule for repeated problems (console and ground station alike): first onset and its
clearing said at once, repeats within the interval counted, then one text that says what is
true now, with the count (issue 37: 57 STATUSTEXTs in 22 s for two flapping servos)."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from mavservo.records import Repeats, glossary_text, repeated

KEY = ("servo aileron", "offline")


def test_first_onset_and_clearing_said_repeats_counted_then_summed_up_in_present_words() -> None:
    r = Repeats(interval_s=10.0)
    assert r.onset(KEY, "servo aileron offline", 0.0) == "servo aileron offline"
    assert r.clear(KEY, "servo aileron back online") == "servo aileron back online"
    for k in range(1, 5):  # flapping: counted, not said
        assert r.onset(KEY, "servo aileron offline", float(k)) is None
        assert r.clear(KEY, "servo aileron back online") is None
    assert r.flush(9.9) == []
    (summary,) = r.flush(10.0)
    assert summary.text == "servo aileron back online (offline x5 in 10 s)"
    assert not summary.active
    assert r.counted == 4
    # still offline at the summary: the summary says so, and its clearing is owed
    assert r.onset(KEY, "servo aileron offline", 12.0) is None
    (summary,) = r.flush(20.0)
    assert (summary.text, summary.active) == ("servo aileron offline (x2 in 10 s)", True)
    assert r.clear(KEY, "servo aileron back online") == "servo aileron back online"
    assert r.flush(40.0) == []  # nothing counted: nothing to sum up


def test_keys_are_independent() -> None:
    r = Repeats(interval_s=10.0)
    assert r.onset(KEY, "a", 0.0) == "a"
    assert r.onset(("servo elevator", "offline"), "b", 0.5) == "b"
    assert r.onset(("servo aileron", "fault stall"), "c", 0.6) == "c"
    assert r.onset(KEY, "a", 1.0) is None


@given(st.lists(st.floats(min_value=0.0, max_value=0.5), min_size=1, max_size=400))
def test_a_key_says_at_most_three_texts_per_interval_however_it_flaps(gaps: list[float]) -> None:
    r = Repeats(interval_s=10.0)
    said: list[float] = []
    t = 0.0
    for gap in gaps:
        t += gap
        for text in (r.onset(KEY, "off", t), r.clear(KEY, "on")):
            if text is not None:
                said.append(t)
        said += [t for _ in r.flush(t)]
    for start in said:
        assert sum(1 for s in said if start <= s < start + 10.0) <= 3


def test_the_count_format_and_the_glossary() -> None:
    assert repeated("servo 3 offline", 5, 10.0) == "servo 3 offline (x5 in 10 s)"
    assert repeated("servo 3 back online", 5, 10.0, "offline") == (
        "servo 3 back online (offline x5 in 10 s)"
    )
    words = glossary_text()
    assert "offline = " in words and "lost = " in words and "late = " in words
