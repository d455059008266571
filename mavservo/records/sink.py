"""One run-log file written through an in-memory buffer, cut back to whole records on failure.

Its own module because it is the run log's unit of file I/O, used for every file that is not a
CAN log (``trace.csv``, ``latency.csv``, ``rejections.log``, ``mavlink.tlog``), and it can be
tested alone against a full disk (a symlink to ``/dev/full``).
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path
from typing import Any

from mavservo.records.private_files import create_private

#: a text file's buffer is written out early past this many characters (or bytes)
BUFFER_LIMIT = 256 * 1024


class BufferedSink:
    """One run-log file written through an in-memory buffer, cut back to whole rows on failure.

    The writer thread appends each row (csv) or frame (tlog) to a list, one ``write`` call
    each, the cheapest thing it can do per event (it shares the interpreter lock with the
    scheduler); :meth:`flush` joins and writes them with ``os.write``. When a write fails
    (ENOSPC, EFBIG, EIO) the file is truncated after the last whole record that reached the
    disk, closed, and refuses further data (:attr:`error`).
    """

    def __init__(self, path: Path, text: bool) -> None:
        create_private(path)
        self.path = path
        self._fd: int | None = os.open(path, os.O_WRONLY | os.O_APPEND)
        self._text = text
        self._parts: list[Any] = []
        self._pending = 0  # characters or bytes in _parts
        self.good_size = 0
        self.error: OSError | None = None

    def write(self, data: str | bytes) -> None:
        if self.error is not None:
            raise self.error
        self._parts.append(data)
        self._pending += len(data)
        if self._pending >= BUFFER_LIMIT:
            self.flush()

    def flush(self) -> None:
        if self._fd is None or not self._parts:
            return
        data = "".join(self._parts).encode("utf-8") if self._text else b"".join(self._parts)
        view = memoryview(data)
        written = 0
        try:
            while written < len(view):
                written += os.write(self._fd, view[written:])
        except OSError as exc:
            self.good_size += self._whole_records(data, written)
            self._fail(exc)
            raise
        self.good_size += len(data)
        self._parts.clear()
        self._pending = 0

    def _whole_records(self, data: bytes, written: int) -> int:
        """Bytes of ``data`` up to the end of the last record within its first ``written``."""
        if self._text:
            return data.rfind(b"\n", 0, written) + 1
        end = 0
        for part in self._parts:
            if end + len(part) > written:
                break
            end += len(part)
        return end

    def _fail(self, exc: OSError) -> None:
        self.error = exc
        self._parts.clear()
        self._pending = 0
        fd, self._fd = self._fd, None
        if fd is not None:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, self.good_size)
            with contextlib.suppress(OSError):
                os.close(fd)

    def close(self) -> None:
        try:
            self.flush()
        finally:
            fd, self._fd = self._fd, None
            if fd is not None:
                os.close(fd)
