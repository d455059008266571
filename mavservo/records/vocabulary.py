"""The words the bridge uses for a servo it does not hear, defined once for every output.

Why: a run's console said ``offline (no reply)`` three times while its summary said ``lost 0``
and the ground station was told ``not responding`` (issue 37): three words, and a count that
looked like a contradiction, because "lost" counts replies and "offline" is a servo's state.
The console, the STATUSTEXTs, the stop summary, metrics.json and ``mavservo report`` take their
words from here, and the summary and the report print :data:`GLOSSARY` under their tables.
"""

from __future__ import annotations

OFFLINE = "offline"
"""A servo's state: nobody hears from it (``offline_after_missed`` expected replies in a row
did not come, its pushes stopped, or its frames cannot be sent); counted per servo as
``went_offline``. It is "back online" with the next reply."""
BACK_ONLINE = "back online"
LOST = "lost"
"""A reply expected and never received (timed out, and did not come later either)."""
LATE = "late"
"""A reply that came after ``scheduler.reply_timeout_s``: counted late, not lost."""

GLOSSARY: tuple[tuple[str, str], ...] = (
    (OFFLINE, "times the servo went offline: not heard for several replies in a row"),
    (LOST, "replies that never came"),
    (LATE, "replies that came after the reply timeout (not lost)"),
)
"""(word, meaning) as the summary and the report explain their columns."""


def glossary_text() -> str:
    """``offline = ...; lost = ...; late = ...``: the one definition line of the three."""
    return "; ".join(f"{word} = {meaning}" for word, meaning in GLOSSARY)
