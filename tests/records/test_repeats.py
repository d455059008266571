"""The one rule for repeated problems (console and ground station alike): first onset and its
clearing said at once, repeats within the interval counted, then one text that says what is
true now, with the count; a problem that lasts after flapping said within seconds (issue 37: 57
STATUSTEXTs in 22 s for two flapping servos)."""

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


@given(st.lists(st.tuples(st.booleans(), st.floats(0.0, 3.0)), min_size=1, max_size=300))
def test_a_key_says_a_bounded_number_of_texts_in_any_10_s_however_it_flaps(
    steps: list[tuple[bool, float]],
) -> None:
    r = Repeats(interval_s=10.0)
    said: list[float] = []
    t = 0.0
    for onset, gap in steps:
        t += gap
        text = r.onset(KEY, "off", t) if onset else r.clear(KEY, "on")
        if text is not None:
            said.append(t)
        said += [t for _ in r.flush(t)]
    for start in said:
        assert sum(1 for s in said if start <= s < start + 10.0) <= 6


def test_a_problem_that_lasts_after_flapping_is_said_within_seconds() -> None:
    """A servo that flapped and then stays offline: said LASTING_S after it went, not at the
    interval's end; once per interval."""
    r = Repeats(interval_s=10.0)
    assert r.onset(KEY, "servo aileron offline", 0.0) is not None
    assert r.clear(KEY, "servo aileron back online") is not None
    assert r.onset(KEY, "servo aileron offline", 1.0) is None  # counted: a flap, so far
    assert r.flush(2.9) == []
    (summary,) = r.flush(3.0)  # lasted 2 s: said now
    assert (summary.text, summary.active) == ("servo aileron offline (x2 in 3 s)", True)
    assert r.flush(5.0) == []  # once
    assert r.clear(KEY, "servo aileron back online") == "servo aileron back online"


def test_the_count_format_and_the_glossary() -> None:
    assert repeated("servo 3 offline", 5, 10.0) == "servo 3 offline (x5 in 10 s)"
    assert repeated("servo 3 back online", 5, 10.0, "offline") == (
        "servo 3 back online (offline x5 in 10 s)"
    )
    words = glossary_text()
    assert "offline = " in words and "lost = " in words and "late = " in words
