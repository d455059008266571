"""What went wrong with a run's log, said once per kind: the run log's problem report.

Its own part because every other part of the run log (the files, the size cap, the writer
thread, ``metrics.json`` at close) reports through it, and the rules are one job: a file that
stops working is counted and named once, each kind of problem gets one log line and one
``on_problem`` call (the bridge's event path: console and STATUSTEXT), and everything is kept
for ``metrics.json`` and :meth:`~.runlog.RunLog.outcome`.
"""

from __future__ import annotations

import errno
import logging
from collections.abc import Callable

#: the run log's one logger, whichever of its parts speaks (users filter on its name)
log = logging.getLogger("mavservo.records.runlog")


class RunLogProblems:
    """The run log's failures: per file, per kind, and the counters ``metrics.json`` keeps."""

    def __init__(self, on_problem: Callable[[str], None] | None = None) -> None:
        self._on_problem = on_problem
        self._reported: set[str] = set()
        #: every problem's text, in order
        self.problems: list[str] = []
        #: file name -> why it stopped
        self.failed_files: dict[str, str] = {}
        self.write_errors = 0
        self.last_error: str | None = None

    def file_failed(self, name: str, exc: OSError) -> None:
        """A file stopped working: count it, and say it once per kind of error."""
        if name in self.failed_files:
            return
        self.failed_files[name] = f"{exc.strerror or exc}"
        self.write_errors += 1
        self.last_error = f"{name}: {exc.strerror or exc}"
        kind = errno.errorcode.get(exc.errno or 0, "error")
        self.report(
            kind,
            f"run log: cannot write {name} ({exc.strerror or exc}); that file stops here,"
            " complete up to the last second (the bridge keeps running)",
        )

    def event_failed(self, exc: Exception) -> None:
        """One odd event could not be written (not a file's fault): counted, not reported."""
        self.write_errors += 1
        self.last_error = f"{type(exc).__name__}: {exc}"

    def report(self, kind: str, text: str) -> None:
        """One log line and one ``on_problem`` call per kind of problem; all kept in problems."""
        self.problems.append(text)
        if kind in self._reported:
            log.debug("%s", text)
            return
        self._reported.add(kind)
        log.error("%s", text)
        if self._on_problem is not None:
            try:
                self._on_problem(text)
            except Exception:  # noqa: BLE001 - a broken listener must not stop the writer
                log.debug("on_problem failed", exc_info=True)
