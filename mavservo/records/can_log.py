"""The run's CAN logs: python-can's rotating writers, one per format, and how to read them back.

A part of its own because CAN logging is python-can's file formats (ASC, BLF, ...), their
rotation and BLF's container-and-header dance, none of which the rest of the run log needs
to know: :class:`CanFrameLogs` takes a ``can.Message`` and puts it in every format's file,
:func:`read_can_log` gives the frames back. ``mavservo report`` and the tests read the files
through :func:`can_log_files`/:func:`read_can_log`, so the layout lives next to the writer.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import stat
import struct
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import can
from can.io.generic import FileIOMessageWriter

from mavservo.records.private_files import create_private

CAN_BASENAME = "can"

#: the run log's one logger, whichever of its parts speaks (users filter on its name)
log = logging.getLogger("mavservo.records.runlog")


def can_log_files(directory: str | os.PathLike[str], fmt: str) -> list[Path]:
    """The CAN log files of one format in write order: rotated parts by count, then the live one.

    python-can's ``SizedRotatingLogger`` renames full files to ``can_<date>_#NNN.<fmt>``.
    """
    directory = Path(directory)
    pattern = re.compile(rf"^{CAN_BASENAME}_.*_#(\d+)\.{re.escape(fmt)}$")
    rotated = []
    for path in directory.iterdir():
        match = pattern.match(path.name)
        if match:
            rotated.append((int(match.group(1)), path.name, path))
    files = [path for _, _, path in sorted(rotated)]
    live = directory / f"{CAN_BASENAME}.{fmt}"
    if live.exists():
        files.append(live)
    return files


def read_can_log(directory: str | os.PathLike[str], fmt: str = "blf") -> list[can.Message]:
    """Every frame of a run's CAN log in one format, across rotated files, via ``can.LogReader``."""
    frames: list[can.Message] = []
    # ASC stores times relative to its header date unless asked for absolute ones.
    options = {"relative_timestamp": False} if fmt == "asc" else {}
    for path in can_log_files(directory, fmt):
        # A killed run can end mid-container: keep every frame before the torn end.
        with (
            contextlib.suppress(struct.error, can.io.blf.BLFParseError, ValueError),
            can.LogReader(path, **options) as reader,
        ):
            for message in reader:
                frames.append(message)
    return frames


def cut_after_last_newline(path: Path, floor: int, chunk: int = 64 * 1024) -> None:
    """Truncate a regular text file after its last newline at or beyond ``floor`` bytes."""
    if not stat.S_ISREG(os.stat(path).st_mode):
        return
    with open(path, "rb+") as handle:
        end = handle.seek(0, os.SEEK_END)
        while end > floor:
            start = max(floor, end - chunk)
            handle.seek(start)
            newline = handle.read(end - start).rfind(b"\n")
            if newline >= 0:
                handle.truncate(start + newline + 1)
                return
            end = start
        handle.truncate(floor)


def _file_writer(writer: can.io.generic.MessageWriter) -> FileIOMessageWriter[Any]:
    """The rotating logger's writer as the file writer it is: every format it rotates (asc,
    blf, csv, log, txt) writes a file, whose ``file`` is flushed and measured here."""
    if not isinstance(writer, FileIOMessageWriter):
        raise TypeError(f"can log: {type(writer).__name__} does not write a file")
    return writer


def _blf_pending(writer: object) -> int | None:
    """Bytes a BLF writer holds for its next container; None for other writers.

    ``_buffer_size`` is python-can's private attribute (4.3-4.6), read by name because a
    version without it must not break logging: its containers then reach the disk at stop.
    """
    value = getattr(writer, "_buffer_size", None)
    return value if isinstance(value, int) else None


#: a BLF writer holding this many frames is flushed at once, besides the run log's flush every
#: second: a killed run's can.blf then lacks at most this many frames of what reached the
#: writer, about what can.asc loses (Python's 8 KiB file buffer: ~130 ASC lines). Why: with
#: the flush each second alone, ``kill -9`` left can.blf 714 of 17,997 frames short on a
#: loaded machine (the flush thread late) while can.asc was nearly whole (issue 37).
BLF_FLUSH_FRAMES = 100


class RotatingCanLog(can.SizedRotatingLogger):
    """python-can's size-rotating logger with private files and a flush that reaches the disk.

    BLF (python-can's :class:`can.BLFWriter`) buffers frames into 128 KiB containers and writes
    its header, which holds the start time every frame is relative to, only at ``stop``: a
    killed run lost the last ~5 s and read back with times from 1970. :meth:`flush` writes the
    pending container and rewrites the header (wall-clock start, size, object count) each
    second and every :data:`BLF_FLUSH_FRAMES` frames, using the writer's
    ``_flush``/``_write_header`` (python-can 4.3-4.6; a writer without them is flushed at stop
    only, as before). On a failed write the file is cut back
    to its last whole line (text formats) or container (BLF) on disk, and the logger stops.
    """

    def __init__(self, base_filename: Path, max_bytes: int, start_wall: float) -> None:
        self._start_wall = start_wall
        self._unflushed = 0  # frames handed to a BLF writer since its last flush
        self.good_size = 0
        self.error: OSError | None = None
        super().__init__(base_filename=base_filename, max_bytes=max_bytes)

    def _get_new_writer(self, filename: Any) -> Any:
        create_private(filename)
        writer = _file_writer(super()._get_new_writer(filename))
        if isinstance(writer, can.BLFWriter) and hasattr(writer, "_write_header"):
            # relative times count from the run's start, to the millisecond BLF stores
            writer.start_timestamp = int(self._start_wall * 1000) / 1000
            self._rewrite_blf_header(writer)
        writer.file.flush()  # the header on disk: a file cut back on failure keeps it
        self.good_size = writer.file.tell()
        return writer

    @staticmethod
    def _rewrite_blf_header(writer: Any) -> None:
        end = writer.file.tell()
        writer.file.seek(0)
        writer._write_header(max(end, 144))  # 144: BLF's file header size
        writer.file.seek(end)

    def on_message_received(self, msg: can.Message) -> None:
        writer = _file_writer(self.writer)
        pending = _blf_pending(writer)  # BLF: bytes waiting for a container
        try:
            super().on_message_received(msg)
            after = _blf_pending(writer)
            wrote_container = pending is not None and after is not None and after < pending
            if self.writer is writer and wrote_container:
                # BLF just wrote a container: put it on disk, so a failure keeps it
                writer.file.flush()
                self.good_size = writer.file.tell()
                self._unflushed = 0
            elif pending is not None:
                self._unflushed += 1
        except OSError as exc:
            self._fail(exc)
            raise
        if self._unflushed >= BLF_FLUSH_FRAMES:
            self.flush()

    def flush(self) -> None:
        """Everything handed in so far onto the disk (the BLF header made current)."""
        if self.error is not None:
            return
        writer = _file_writer(self.writer)
        try:
            if isinstance(writer, can.BLFWriter) and hasattr(writer, "_flush"):
                writer._flush()
                self._rewrite_blf_header(writer)
            writer.file.flush()
            self.good_size = writer.file.tell()
            self._unflushed = 0
        except OSError as exc:
            self._fail(exc)
            raise

    def _fail(self, exc: OSError) -> None:
        """Close the file (not ``stop()``: no end block) and cut it back to the last flush.

        By name, after closing: the file object still holds the tail that failed, and closing
        tries to write it once more (it may partly succeed under a size limit).
        """
        self.error = exc
        blf = isinstance(self.writer, can.BLFWriter)
        with contextlib.suppress(Exception):
            _file_writer(self.writer).file.close()
        with contextlib.suppress(OSError):
            if blf:  # cut after the last container known to be on disk
                os.truncate(self.base_filename, self.good_size)
            else:  # text formats: keep every whole line that reached the disk
                cut_after_last_newline(Path(self.base_filename), self.good_size)

    def stop(self) -> None:
        if self.error is None:
            super().stop()


class CanFrameLogs:
    """Every configured format's CAN log (``can.<fmt>`` in ``directory``), fed frame by frame.

    One full or broken log does not stop the others: a failed write, flush or close is handed
    to ``on_failed(file name, error)`` (the run log's problem report) and that log stays shut.
    """

    def __init__(
        self,
        directory: Path,
        formats: Iterable[str],
        rotate_bytes: int,
        start_wall: float,
        on_failed: Callable[[str, OSError], None],
    ) -> None:
        self.formats = tuple(formats)
        self._on_failed = on_failed
        self._loggers = [
            RotatingCanLog(directory / f"{CAN_BASENAME}.{fmt}", rotate_bytes, start_wall)
            for fmt in self.formats
        ]

    def write(self, msg: can.Message) -> None:
        for logger in self._loggers:
            if logger.error is not None:
                continue
            try:
                logger.on_message_received(msg)
            except OSError as exc:
                self._on_failed(Path(logger.base_filename).name, exc)

    def flush(self) -> None:
        for logger in self._loggers:
            try:
                logger.flush()
            except OSError as exc:
                self._on_failed(Path(logger.base_filename).name, exc)

    def close(self) -> None:
        for logger in self._loggers:
            try:
                logger.stop()
            except OSError as exc:
                self._on_failed(Path(logger.base_filename).name, exc)
            except Exception:  # noqa: BLE001 - closing goes on with the other files
                log.debug("closing a CAN log failed", exc_info=True)
