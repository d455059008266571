"""Benchmark of the AA-55 transport against python-can's ``seeedstudio`` driver (run by hand).

Why this exists: the ``aa55`` interface claims to be much faster and more robust than python-can's
``seeedstudio`` driver, which decodes the same wire format one byte per read. This script checks
the claim on the same byte streams, in the same run, and prints a markdown table for
docs/benchmarks.md. Measured:

* (a) decoding bytes already in memory: seeedstudio fed from an in-memory fake port, against
  ``Decoder.feed`` on 4096-byte chunks (alone, and with the ``can.Message`` conversion a bus user
  pays for);
* (b) the whole interface reading a pseudo-terminal through pyserial, ``bus.recv()`` in a loop,
  with a separate writer process pushing the pre-encoded stream into the master side;
* the receiving thread's CPU time at a saturated 2 Mbaud line (paced writer);
* robustness on a seeded corrupted stream, with per-frame ground truth to classify every output.

Usage::

    python bench/bench_aa55.py --repeat 5

Timing figures are medians over ``--repeat`` runs; ratios are computed within each run, then
their median is taken, so a slow moment of the shared machine hits both sides of a ratio.
"""

from __future__ import annotations

import argparse
import bisect
import io
import multiprocessing
import os
import platform
import random
import select
import statistics
import struct
import sys
import time
import tty
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import can
import serial
from can.interfaces.seeedstudio.seeedstudio import SeeedBus

from mavservo.transport.aa55.codec import MAX_EXT_ID, MAX_STD_ID, Decoder, Frame, encode

#: 2 Mbaud with 10 bits per byte (start + 8 + stop) and 13-byte frames (std ID, 8 data bytes).
SATURATED_FPS = 15_400
CHUNK = 4096
#: How long ``recv`` may see nothing before a pty run is declared over (the writer is done or
#: the reader lost sync); bounds every receive loop.
IDLE_TIMEOUT_S = 1.0
#: Truth frames searched ahead for a match when classifying a decoder's output (frames can be
#: lost, so the pointer must be allowed to skip some).
MATCH_WINDOW = 64

Key = tuple[int, bool, bool, int, bytes]


# -- streams ------------------------------------------------------------------------------------


def throughput_frames(n: int, seed: int) -> list[Frame]:
    """Standard-ID frames with 8 random data bytes: 13 bytes on the wire, as servo traffic is.

    Random payloads contain 0xAA and 0x55 now and then, which is what a real line carries.
    """
    rng = random.Random(seed)
    return [
        Frame(rng.randrange(MAX_STD_ID + 1), False, False, 8, rng.randbytes(8)) for _ in range(n)
    ]


def mixed_frames(n: int, seed: int) -> list[Frame]:
    """Frames of random layouts (30% extended, DLC 0-8): consecutive frames rarely share one."""
    rng = random.Random(seed)
    return [_random_frame(rng) for _ in range(n)]


def encode_stream(frames: Sequence[Frame], protocol: str = "variable") -> bytes:
    """The wire bytes of ``frames`` back to back (the clean stream both decoders read)."""
    return b"".join(encode(f, protocol) for f in frames)  # type: ignore[arg-type]


INTACT, FLIPPED, TRUNCATED = "intact", "flipped", "truncated"


@dataclass
class Corrupted:
    """A corrupted stream and, per frame sent, the frame and what happened to it on the wire."""

    stream: bytes
    frames: list[Frame]
    status: list[str]
    #: Where each frame's (possibly damaged) bytes begin in ``stream``, after any garbage.
    offsets: list[int] = field(default_factory=list)


def corrupted_stream(
    n: int,
    seed: int,
    protocol: str = "variable",
    p_garbage: float = 0.05,
    p_flip: float = 0.02,
    p_truncate: float = 0.01,
) -> Corrupted:
    """A seeded stream: 1-5 garbage bytes before ``p_garbage`` of the frames, one flipped byte in
    ``p_flip`` of them, the tail cut off ``p_truncate`` of them.

    The garbage bytes are 0xAA a quarter of the time (uniform otherwise): uniform noise almost
    never contains a start byte, so it would not test resynchronisation at all. Frames are
    data frames (seeedstudio misreads remote frames, see docs/engineering/architecture.md), standard
    or extended, DLC 0-8, and no frame repeats one of the previous ``MATCH_WINDOW`` ones, so an
    output matches at most one truth frame.
    """
    rng = random.Random(seed)
    out = bytearray()
    frames: list[Frame] = []
    status: list[str] = []
    offsets: list[int] = []
    recent: list[Key] = []
    for _ in range(n):
        frame = _random_frame(rng)
        for _retry in range(100):  # bounded: a collision has probability ~1e-3
            if frame.key() not in recent:
                break
            frame = _random_frame(rng)
        recent.append(frame.key())
        if len(recent) > MATCH_WINDOW:
            recent.pop(0)
        raw = bytearray(encode(frame, protocol))  # type: ignore[arg-type]
        if rng.random() < p_garbage:
            out += bytes(
                0xAA if rng.random() < 0.25 else rng.randrange(256)
                for _ in range(rng.randint(1, 5))
            )
        r = rng.random()
        if r < p_truncate:
            raw = raw[: rng.randint(1, len(raw) - 1)]
            state = TRUNCATED
        elif r < p_truncate + p_flip:
            raw[rng.randrange(len(raw))] ^= rng.randint(1, 255)
            state = FLIPPED
        else:
            state = INTACT
        offsets.append(len(out))
        out += raw
        frames.append(frame)
        status.append(state)
    return Corrupted(bytes(out), frames, status, offsets)


def _random_frame(rng: random.Random) -> Frame:
    ext = rng.random() < 0.3
    dlc = rng.randint(0, 8)
    arb_id = rng.randrange((MAX_EXT_ID if ext else MAX_STD_ID) + 1)
    return Frame(arb_id, ext, False, dlc, rng.randbytes(dlc))


# -- decoders on bytes in memory ------------------------------------------------------------------


class FakePort:
    """Just enough of a pyserial port for ``SeeedBus._recv_internal``: reads from memory.

    ``read()`` must default to one byte: seeedstudio calls ``ser.read()`` for single bytes.
    """

    def __init__(self, data: bytes) -> None:
        self._rx = io.BytesIO(data)
        self.tell = self._rx.tell
        self.tx = bytearray()

    def read(self, n: int = 1) -> bytes:
        return self._rx.read(n)

    def write(self, data: bytes) -> int:
        self.tx += data
        return len(data)


def seeed_on_bytes(stream: bytes) -> list[tuple[can.Message, bytes]]:
    """Every message seeedstudio decodes from ``stream``, with the raw bytes it consumed for it.

    The loop is bounded: each call consumes at least one byte until the stream is exhausted.
    Running out of bytes mid-frame raises (TypeError / struct.error) in seeedstudio; that ends
    the candidate as the driver would end it on a real port.
    """
    bus = SeeedBus.__new__(SeeedBus)
    port = FakePort(stream)
    bus.ser = port
    recv = bus._recv_internal
    tell = port.tell
    size = len(stream)
    out: list[tuple[can.Message, bytes]] = []
    for _ in range(size + 1):
        before = tell()
        if before >= size:
            break
        try:
            msg, _ = recv(0)
        except (TypeError, struct.error):
            continue
        if msg is not None:
            out.append((msg, stream[before : tell()]))
    return out


def seeed_count(stream: bytes) -> int:
    """Messages seeedstudio decodes from a clean ``stream`` (the timed path, no bookkeeping)."""
    bus = SeeedBus.__new__(SeeedBus)
    port = FakePort(stream)
    bus.ser = port
    recv = bus._recv_internal
    tell = port.tell
    size = len(stream)
    count = 0
    for _ in range(size + 1):
        if tell() >= size:
            break
        try:
            msg, _ = recv(0)
        except (TypeError, struct.error):
            continue
        if msg is not None:
            count += 1
    return count


def ours_on_bytes(stream: bytes, protocol: str = "variable", chunk: int = CHUNK) -> list[Frame]:
    """Data frames ``Decoder.feed`` yields from ``stream`` fed in ``chunk``-byte pieces, then
    ``flush`` (the line goes idle at the end of the stream)."""
    dec = Decoder(protocol)  # type: ignore[arg-type]
    out: list[Any] = []
    for i in range(0, len(stream), chunk):
        out += dec.feed(stream[i : i + chunk])
    out += dec.flush()
    return [f for f in out if type(f) is Frame]


def ours_messages(stream: bytes, chunk: int = CHUNK) -> list[can.Message]:
    """As :func:`ours_on_bytes`, plus the ``can.Message`` conversion the ``aa55`` bus does."""
    dec = Decoder()
    out: list[can.Message] = []
    for i in range(0, len(stream), chunk):
        out += [f.to_message("bench") for f in dec.feed(stream[i : i + chunk]) if type(f) is Frame]
    return out


def ours_count(stream: bytes, to_message: bool = False, chunk: int = CHUNK) -> int:
    """Data frames our decoder yields from a clean ``stream`` (the timed path).

    Like :func:`seeed_count`, each frame is made and dropped, not kept: keeping 200,000 objects
    alive would bill the garbage collector's passes over them to whichever decoder keeps them.
    ``to_message`` adds the ``can.Message`` conversion the ``aa55`` bus does for each frame.
    """
    dec = Decoder()
    count = 0
    for i in range(0, len(stream), chunk):
        for f in dec.feed(stream[i : i + chunk]):
            if type(f) is Frame:
                if to_message:
                    f.to_message("bench")
                count += 1
    return count


def _rate(fn: Callable[[], int]) -> float:
    """Frames per second of one call of ``fn`` (which returns the frame count)."""
    t0 = time.perf_counter()
    count = fn()
    return count / (time.perf_counter() - t0)


def bench_memory(stream: bytes) -> dict[str, float]:
    """One run of (a): frames/s of seeedstudio, ours (Frame) and ours (can.Message).

    The three are interleaved in one run so that the ratios compare like with like.
    """
    rates = {
        "seeed": _rate(lambda: seeed_count(stream)),
        "ours": _rate(lambda: ours_count(stream)),
        "ours_msg": _rate(lambda: ours_count(stream, to_message=True)),
    }
    return rates


# -- pseudo-terminal ----------------------------------------------------------------------------


def _push(master: int, stream: bytes, fps: float | None, frame_len: int, period: float) -> None:
    """Writer process body: put ``stream`` into the pty master, flat out or paced at ``fps``.

    Paced mode writes one batch every ``period`` seconds (a USB-serial adapter also delivers in
    bursts, once per USB frame), sleeping to an absolute schedule so errors do not accumulate.
    """
    if fps is None:
        for i in range(0, len(stream), 65536):
            _write_all(master, stream[i : i + 65536])
        return
    per_batch = max(1, round(fps * period)) * frame_len
    t0 = time.monotonic()
    for k, i in enumerate(range(0, len(stream), per_batch)):
        delay = t0 + k * period - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        _write_all(master, stream[i : i + per_batch])


def _write_all(fd: int, data: bytes) -> None:
    """``os.write`` until all of ``data`` is out: a pty may accept only part of a write."""
    view = memoryview(data)
    for _ in range(len(data) + 1):  # bounded: each blocking write moves at least one byte
        if not view:
            return
        view = view[os.write(fd, view) :]


@contextmanager
def pty_pair() -> Iterator[tuple[int, str]]:
    """A raw-mode pseudo-terminal: yields (master fd, slave path); closes both afterwards.

    The slave fd stays open in this process so the pty survives bus open/close cycles.
    """
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        yield master, os.ttyname(slave)
    finally:
        os.close(master)
        os.close(slave)


def _drain(master: int) -> int:
    """Read (and drop) what the bus wrote towards the adapter, e.g. its settings/init frame."""
    os.set_blocking(master, False)
    total = 0
    try:
        for _ in range(1000):  # bounded; a settings frame is 20 bytes
            try:
                chunk = os.read(master, 4096)
            except BlockingIOError:
                break
            if not chunk:
                break
            total += len(chunk)
    finally:
        os.set_blocking(master, True)
    return total


def open_bus(kind: str, channel: str, **options: Any) -> can.BusABC:
    """The bus under test on the pty slave: ``aa55`` (ours, with ``options``) or ``seeedstudio``."""
    if kind == "aa55":
        return can.Bus(interface="aa55", channel=channel, **options)
    return can.Bus(interface="seeedstudio", channel=channel, baudrate=2_000_000)


@dataclass
class PtyResult:
    """What one pty run saw: frames, wall time first-to-last frame, receiving-thread CPU time."""

    frames: int
    wall: float
    cpu: float
    init_bytes: int
    keys: list[Key] = field(default_factory=list)

    @property
    def fps(self) -> float:
        return (self.frames - 1) / self.wall if self.wall > 0 and self.frames > 1 else 0.0

    @property
    def cpu_percent(self) -> float:
        return 100.0 * self.cpu / self.wall if self.wall > 0 else 0.0


def run_pty(
    kind: str,
    stream: bytes,
    n_frames: int,
    fps: float | None = None,
    frame_len: int = 13,
    period: float = 0.001,
    keep_keys: bool = False,
    **options: Any,
) -> PtyResult:
    """Receive ``stream`` through a pty with ``bus.recv()`` until ``n_frames`` arrived.

    The writer is a separate process (fork) so it competes with the reader for a core, as a
    kernel driver would, but not for the GIL. Wall and CPU time run from the first frame to
    the last (process start-up is not the reader's cost); in paced mode the CPU figure is this
    thread's CPU time (``time.thread_time``) as a percentage of that wall time.
    """
    ctx = multiprocessing.get_context("fork")
    with pty_pair() as (master, path):
        bus = open_bus(kind, path, **options)
        try:
            init_bytes = _drain(master)
            writer = ctx.Process(target=_push, args=(master, stream, fps, frame_len, period))
            writer.start()
            try:
                got = 0
                keys: list[Key] = []
                t_first = c_first = t_last = 0.0
                for _ in range(n_frames + 1000):  # bounded; ends on n_frames or idle
                    msg = bus.recv(timeout=IDLE_TIMEOUT_S)
                    if msg is None:
                        break
                    got += 1
                    t_last = time.perf_counter()
                    if got == 1:
                        # thread_time() is a real system call (~1 us): not once per frame
                        t_first, c_first = t_last, time.thread_time()
                    if keep_keys:
                        keys.append(_msg_key(msg))
                    if got >= n_frames:
                        break
                # after an idle timeout this adds ~0 CPU: the thread was blocked in select
                c_last = time.thread_time()
            finally:
                writer.join(timeout=10)
                if writer.is_alive():
                    writer.terminate()
                    writer.join(timeout=2)
        finally:
            bus.shutdown()
    return PtyResult(got, t_last - t_first, c_last - c_first, init_bytes, keys)


def _msg_key(msg: can.Message) -> Key:
    return (
        msg.arbitration_id,
        msg.is_extended_id,
        msg.is_remote_frame,
        msg.dlc,
        bytes(msg.data),
    )


# -- robustness ---------------------------------------------------------------------------------


@dataclass
class Robustness:
    """Outputs of one decoder on a corrupted stream, classified against the ground truth."""

    decoder: str
    intact: int
    intact_recovered: int
    damaged_emitted_as_sent: int
    wrong_undetectable: int
    wrong_impossible: int
    #: Indices (into the truth) of the intact frames no output matched.
    lost: list[int] = field(default_factory=list)
    #: Of those, the losses a clean stream forces (see :func:`forced_losses`).
    lost_forced: int = 0

    @property
    def intact_lost(self) -> int:
        return self.intact - self.intact_recovered

    @property
    def recoverable_percent(self) -> float:
        """Recovered intact frames out of those no clean stream carries as part of another."""
        recoverable = self.intact - self.lost_forced
        return 100.0 * self.intact_recovered / recoverable if recoverable else 100.0

    @property
    def recovered_percent(self) -> float:
        return 100.0 * self.intact_recovered / self.intact if self.intact else 100.0

    @property
    def wrong(self) -> int:
        return self.wrong_undetectable + self.wrong_impossible


def is_impossible(key: Key, stream: bytes | None, raw: bytes | None = None) -> bool:
    """True for a frame no valid AA-55 frame on the line could have produced.

    That is an ID out of range, DLC > 8, a data length that disagrees with the DLC, a remote
    frame carrying data, or a bad type byte. The type byte is checked on ``raw`` when the
    decoder reports the bytes it consumed; otherwise (our decoder does not) by requiring the
    frame's canonical variable-protocol encoding, which has a valid type byte, to occur in
    ``stream`` (skipped when ``stream`` is None: the fixed protocol has no type byte).
    """
    arb_id, ext, rtr, dlc, data = key
    if arb_id > (MAX_EXT_ID if ext else MAX_STD_ID) or dlc > 8:
        return True
    if len(data) != (0 if rtr else dlc):
        return True
    if raw is not None and (len(raw) < 2 or raw[1] & 0xC0 != 0xC0):
        return True
    try:
        canonical = encode(Frame(arb_id, ext, rtr, dlc, data))
    except ValueError:
        return True
    return stream is not None and canonical not in stream


def classify(
    name: str,
    truth: Corrupted,
    outputs: Sequence[Key],
    raws: Sequence[bytes] | None,
    stream: bytes | None,
    protocol: str = "variable",
) -> Robustness:
    """Match outputs, in order, to the truth frames (searching ``MATCH_WINDOW`` ahead).

    An output equal to a sent frame is that frame; any other output is a wrong frame, split
    into impossible (see :func:`is_impossible`) and undetectable (structurally valid, e.g. a
    flipped payload byte: a checksum-free protocol cannot catch it). ``raws`` are the bytes the
    decoder consumed per output, when it tells; ``stream`` is the variable-protocol stream it
    read, or None for the fixed protocol.
    """
    keys = [f.key() for f in truth.frames]
    pos = 0
    matched: set[int] = set()
    recovered = damaged_ok = undetectable = impossible = 0
    for i, out in enumerate(outputs):
        hit = -1
        for j in range(pos, min(pos + MATCH_WINDOW, len(keys))):
            if keys[j] == out:
                hit = j
                break
        if hit >= 0:
            matched.add(hit)
            if truth.status[hit] == INTACT:
                recovered += 1
            else:
                damaged_ok += 1
            pos = hit + 1
        elif is_impossible(out, stream, raws[i] if raws is not None else None):
            impossible += 1
        else:
            undetectable += 1
    intact = truth.status.count(INTACT)
    lost = [i for i, state in enumerate(truth.status) if state == INTACT and i not in matched]
    result = Robustness(name, intact, recovered, damaged_ok, undetectable, impossible, lost)
    if truth.offsets:
        result.lost_forced = len(forced_losses(truth, outputs, lost, protocol))
    return result


def output_spans(stream: bytes, outputs: Sequence[Key], protocol: str) -> list[tuple[int, int]]:
    """Where each output's wire bytes sit in ``stream``: (start, end), or (-1, -1) when the
    output has no valid encoding (an impossible frame) or its bytes are not found.

    Outputs come in stream order and never share bytes, so each is searched for from where the
    previous one ended.
    """
    spans = []
    at = 0
    for key in outputs:
        try:
            raw = encode(Frame(*key), protocol)  # type: ignore[arg-type]
        except ValueError:
            spans.append((-1, -1))
            continue
        start = stream.find(raw, at)
        if start < 0:
            spans.append((-1, -1))
            continue
        at = start + len(raw)
        spans.append((start, at))
    return spans


def forced_losses(
    truth: Corrupted, outputs: Sequence[Key], lost: Sequence[int], protocol: str = "variable"
) -> list[int]:
    """The lost intact frames that no decoder correct on clean streams could have recovered.

    A lost frame is certified when the decoder emitted a valid frame X whose bytes cover it and
    X is flanked by the frames emitted before and after it, back to back: then the bytes from
    the frame before to the frame after are, byte for byte, the clean stream ``P X N``, which
    must decode to X. A decoder that decides from the frames around a candidate (as any
    streaming decoder with bounded look-ahead does) cannot tell the corrupted stream from that
    clean one, so it must lose the frame inside X. (A truncated frame whose length runs exactly
    to the next frame's end, or a garbage 0xAA right after a frame, makes such an X.)
    """
    spans = output_spans(truth.stream, outputs, protocol)
    found = [(s, i) for i, (s, _) in enumerate(spans) if s >= 0]  # sorted: outputs in order
    starts = [s for s, _ in found]
    forced = []
    for j in lost:
        first = truth.offsets[j]
        last = first + len(encode(truth.frames[j], protocol))  # type: ignore[arg-type]
        k = bisect.bisect_left(starts, first) - 1  # the last output starting before the frame
        if k < 0:
            continue
        i = found[k][1]
        start, stop = spans[i]
        if stop < last:
            continue
        before_ok = i == 0 or spans[i - 1][1] == start
        after_ok = i + 1 == len(spans) or spans[i + 1][0] == stop
        if before_ok and after_ok:
            forced.append(j)
    return forced


def bench_robustness(n: int, seed: int) -> list[Robustness]:
    """Both decoders on the same seeded variable-protocol stream; ours on the fixed protocol."""
    var = corrupted_stream(n, seed, "variable")
    seeed = seeed_on_bytes(var.stream)
    results = [
        classify(
            "seeedstudio",
            var,
            [_msg_key(m) for m, _ in seeed],
            [raw for _, raw in seeed],
            var.stream,
        ),
        classify(
            "aa55 (ours)", var, [f.key() for f in ours_on_bytes(var.stream)], None, var.stream
        ),
    ]
    fixed = corrupted_stream(n, seed, "fixed")
    results.append(
        classify(
            "aa55 (ours), fixed protocol",
            fixed,
            [f.key() for f in ours_on_bytes(fixed.stream, "fixed")],
            None,
            None,
            "fixed",
        )
    )
    return results


def bench_robustness_seeds(n: int, seed: int, seeds: int) -> list[Robustness]:
    """:func:`bench_robustness` on ``seeds`` streams (seed, seed + 1, ...), counts summed."""
    runs = [bench_robustness(n, s) for s in range(seed, seed + seeds)]
    totals = []
    for per_decoder in zip(*runs, strict=True):
        first = per_decoder[0]
        totals.append(
            Robustness(
                first.decoder,
                *(
                    sum(getattr(r, name) for r in per_decoder)
                    for name in (
                        "intact",
                        "intact_recovered",
                        "damaged_emitted_as_sent",
                        "wrong_undetectable",
                        "wrong_impossible",
                    )
                ),
                lost_forced=sum(r.lost_forced for r in per_decoder),
            )
        )
    return totals


# -- report -------------------------------------------------------------------------------------


def machine() -> str:
    """``uname -m``, CPU model, core count and Python version, for the record."""
    model = "unknown CPU"
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return (
        f"{platform.machine()}, {model}, {os.cpu_count()} cores, "
        f"Python {platform.python_version()}, python-can {can.__version__}"
    )


def _med(values: Sequence[float]) -> float:
    return statistics.median(values) if values else float("nan")


def run(args: argparse.Namespace) -> str:
    """Run every enabled measurement and return the markdown report."""
    lines: list[str] = []
    rows: list[str] = []
    if not args.skip_memory:
        frames = throughput_frames(args.frames, args.seed)
        stream = encode_stream(frames)
        assert seeed_count(stream) == len(frames) == len(ours_on_bytes(stream))
        runs = [bench_memory(stream) for _ in range(args.repeat)]
        seeed = _med([r["seeed"] for r in runs])
        for key, label in (("ours", "Frame"), ("ours_msg", "can.Message")):
            ratio = _med([r[key] / r["seeed"] for r in runs])
            rows.append(
                f"| (a) decoder, bytes in memory -> {label} | {seeed:,.0f} frames/s | "
                f"{_med([r[key] for r in runs]):,.0f} frames/s | {ratio:.1f}x | >= 5x | "
                f"{'yes' if ratio >= 5 else 'no'} |"
            )
        mixed = encode_stream(mixed_frames(args.frames, args.seed))
        runs = [bench_memory(mixed) for _ in range(args.repeat)]
        rows.append(
            f"| (a') as (a), every frame a random layout (std/ext, DLC 0-8, no runs) -> Frame | "
            f"{_med([r['seeed'] for r in runs]):,.0f} frames/s | "
            f"{_med([r['ours'] for r in runs]):,.0f} frames/s | "
            f"{_med([r['ours'] / r['seeed'] for r in runs]):.1f}x | (info) | |"
        )
    if not args.skip_pty:
        frames = throughput_frames(args.pty_frames, args.seed + 1)
        stream = encode_stream(frames)
        pairs = []
        for _ in range(args.repeat):
            s = run_pty("seeedstudio", stream, len(frames))
            o = run_pty("aa55", stream, len(frames))
            if s.frames != len(frames) or o.frames != len(frames):
                lines.append(f"WARNING: pty run lost frames (seeed {s.frames}, ours {o.frames})")
            pairs.append((s.fps, o.fps))
        seeed = _med([s for s, _ in pairs])
        ratio = _med([o / s for s, o in pairs])
        rows.append(
            f"| (b) interface over a pty, `bus.recv()` | {seeed:,.0f} frames/s | "
            f"{_med([o for _, o in pairs]):,.0f} frames/s | {ratio:.1f}x | >= 10x | "
            f"{'yes' if ratio >= 10 else 'no'} |"
        )
    if not args.skip_cpu:
        rows += cpu_rows(args)
    if rows:
        lines += [
            "| measurement | seeedstudio | aa55 (ours) | ratio | goal | met |",
            "|---|---:|---:|---:|---|---|",
            *rows,
            "",
        ]
    if not args.skip_robustness:
        lines += [
            f"Corrupted stream: {args.robust_frames:,} frames x {args.robust_seeds} seed(s) from "
            f"{args.seed}; garbage before 5%, one flipped byte in 2%, truncated tail in 1%.",
            "",
            "| decoder | intact recovered | intact lost | of which forced | recovered of the "
            "rest | wrong: undetectable | wrong: impossible | damaged but emitted as sent |",
            "|---|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for r in bench_robustness_seeds(args.robust_frames, args.seed, args.robust_seeds):
            lines.append(
                f"| {r.decoder} | {r.intact_recovered:,} / {r.intact:,} "
                f"({r.recovered_percent:.2f}%) | {r.intact_lost:,} | {r.lost_forced:,} | "
                f"{r.recoverable_percent:.2f}% | {r.wrong_undetectable:,} | "
                f"{r.wrong_impossible:,} | {r.damaged_emitted_as_sent:,} |"
            )
        lines += [
            "",
            "Forced: the intact frame sits inside bytes that, from the frame emitted before to "
            "the frame emitted after, are a clean stream of three valid frames "
            "(`forced_losses`); a decoder that decodes every clean stream exactly must emit the "
            "outer frame there.",
            "",
        ]
    return "\n".join(lines)


def cpu_rows(args: argparse.Namespace) -> list[str]:
    """Receiving-thread CPU at a saturated 2 Mbaud line: seeedstudio, ours (default ``"auto"``,
    0, and each ``read_interval_s``), and the floor: a bare ``select`` + ``read`` loop on the
    same pty with no decoding at all (what ~1,000 wake-ups a second cost on this machine by
    themselves); then what a wake-up costs by itself (:func:`wake_up_cost`)."""
    n = int(SATURATED_FPS * args.cpu_seconds)
    stream = encode_stream(throughput_frames(n, args.seed + 2))
    period = args.pace_ms / 1000
    intervals = [ms / 1000 for ms in args.read_interval_ms]
    cpu: dict[str, list[float]] = {"seeed": [], "ours": [], "floor": []}
    for _ in range(args.repeat):
        cpu["seeed"].append(
            run_pty("seeedstudio", stream, n, fps=SATURATED_FPS, period=period).cpu_percent
        )
        cpu["ours"].append(run_pty("aa55", stream, n, fps=SATURATED_FPS, period=period).cpu_percent)
        for interval in (0.0, *intervals):
            cpu.setdefault(f"ours_{interval:g}", []).append(
                run_pty(
                    "aa55", stream, n, fps=SATURATED_FPS, period=period, read_interval_s=interval
                ).cpu_percent
            )
        cpu["floor"].append(bare_reader_cpu(stream, period))
    what = (
        f"receiving thread CPU at {SATURATED_FPS:,} frames/s (2 Mbaud, {args.cpu_seconds:g} s, "
        f"a batch every {args.pace_ms:g} ms)"
    )
    seeed = _med(cpu["seeed"])
    rows = []
    for key, label in (
        ("ours", 'default (`read_interval_s="auto"`: spaced reads while the line is busy)'),
        ("ours_0", "`read_interval_s=0` (every USB burst read at once)"),
        *((f"ours_{i:g}", f"`read_interval_s={i:g}`") for i in intervals),
    ):
        ours = _med(cpu[key])
        less = _med([s / o for s, o in zip(cpu["seeed"], cpu[key], strict=True)])
        rows.append(
            f"| {what}, {label} | {seeed:.1f}% of a core | {ours:.1f}% of a core | "
            f"{less:.1f}x less | < 5% | {'yes' if ours < 5 else 'no'} |"
        )
    rows.append(
        f"| the same line read by a bare `select` + `os.read` loop, no decoding (the floor) | | "
        f"{_med(cpu['floor']):.1f}% of a core | | (info) | |"
    )
    warm = _med([receive_cost_per_frame(stream, pause=0.0) for _ in range(args.repeat)])
    cold = _med([receive_cost_per_frame(stream, pause=0.004) for _ in range(args.repeat)])
    rows.append(
        f"| our decode + `can.Message` + `recv()` per frame, 4 ms chunks fed from memory: "
        f"back to back / with a 4 ms sleep before each chunk | | {warm:.2f} us / {cold:.2f} us | "
        f"| (info) | |"
    )
    per_wake = []
    for pause, chunk_frames in ((0.004, 15), (0.004, 60), (0.004, 240), (0.001, 15)):
        extra = _med([wake_up_cost(stream, pause, chunk_frames) for _ in range(args.repeat)])
        per_wake.append(f"{extra:.0f} us ({chunk_frames} frames, {pause * 1000:g} ms)")
    rows.append(
        "| CPU a wake-up adds: a chunk's cost after a sleep minus back to back, per chunk "
        f"(frames per chunk, sleep) | | {' / '.join(per_wake)} | | (info) | |"
    )
    return rows


#: Most chunks one :func:`receive_cost_per_frame` run feeds: with a sleep before each, 500
#: chunks of 4 ms take 2 s.
MAX_CHUNKS = 500


def receive_cost_per_frame(stream: bytes, pause: float, chunk_frames: int = 60) -> float:
    """Thread CPU per frame (us) of decoding, converting and ``recv()``-ing 4 ms chunks.

    The bytes come from memory (no select, no read), so this is the Python work alone. With
    ``pause`` the thread sleeps before each chunk as it does between USB bursts; the difference
    to ``pause=0`` is what a cold cache costs after each sleep on this machine.
    """
    return receive_cost(stream, pause, chunk_frames)[1]


def wake_up_cost(stream: bytes, pause: float, chunk_frames: int) -> float:
    """CPU (us) a sleep of ``pause`` adds to the next chunk of ``chunk_frames`` frames.

    If it stays about the same whatever the chunk size, the cost is per wake-up (caches and
    TLBs refilled after the idle vCPU was halted), not per frame.
    """
    warm = receive_cost(stream, 0.0, chunk_frames)[0]
    return receive_cost(stream, pause, chunk_frames)[0] - warm


def receive_cost(stream: bytes, pause: float, chunk_frames: int = 60) -> tuple[float, float]:
    """Thread CPU (us) per chunk and per frame of receiving ``stream`` in ``chunk_frames``
    chunks fed from memory, sleeping ``pause`` before each (see :func:`receive_cost_per_frame`).
    """
    size = 13 * chunk_frames
    chunks = [stream[i : i + size] for i in range(0, len(stream), size)][:MAX_CHUNKS]
    with pty_pair() as (master, path):
        bus = open_bus("aa55", path)
        try:
            _drain(master)
            cpu = 0.0
            got = 0
            for chunk in chunks:
                if pause:
                    time.sleep(pause)
                c0 = time.thread_time()
                bus._absorb_chunk(chunk)  # what a read of ``chunk`` from the port leads to
                for _ in range(chunk_frames + 1):  # bounded: the chunk's frames, then None
                    if bus.recv(0.0) is None:
                        break
                    got += 1
                cpu += time.thread_time() - c0
        finally:
            bus.shutdown()
    return (1e6 * cpu / len(chunks), 1e6 * cpu / got) if got else (0.0, 0.0)


def bare_reader_cpu(stream: bytes, period: float) -> float:
    """CPU % of a thread that only waits for and reads the paced stream (no decoding)."""
    ctx = multiprocessing.get_context("fork")
    with pty_pair() as (master, path):
        port = serial.Serial(path, 2_000_000, timeout=0)
        try:
            fd = port.fileno()
            writer = ctx.Process(target=_push, args=(master, stream, SATURATED_FPS, 13, period))
            writer.start()
            try:
                got = 0
                select.select([fd], [], [], IDLE_TIMEOUT_S)
                t0, c0 = time.perf_counter(), time.thread_time()
                for _ in range(len(stream)):  # bounded: every turn reads at least one byte
                    ready, _, _ = select.select([fd], [], [], IDLE_TIMEOUT_S)
                    if not ready:
                        break
                    got += len(os.read(fd, 65536))
                    if got >= len(stream):
                        break
                t1, c1 = time.perf_counter(), time.thread_time()
            finally:
                writer.join(timeout=10)
        finally:
            port.close()
    return 100.0 * (c1 - c0) / (t1 - t0) if t1 > t0 else 0.0


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    p.add_argument("--repeat", type=int, default=5, help="timed runs; medians are reported")
    p.add_argument("--frames", type=int, default=200_000, help="frames for (a), in memory")
    p.add_argument("--pty-frames", type=int, default=100_000, help="frames for (b), over a pty")
    p.add_argument("--cpu-seconds", type=float, default=3.0, help="paced run length per decoder")
    p.add_argument(
        "--pace-ms", type=float, default=1.0, help="paced writer: one batch every PACE_MS ms"
    )
    p.add_argument(
        "--read-interval-ms",
        type=float,
        nargs="+",
        default=[4.0, 10.0],
        help="aa55 read_interval_s values for the CPU rows",
    )
    p.add_argument("--robust-frames", type=int, default=100_000, help="corrupted-stream frames")
    p.add_argument(
        "--robust-seeds", type=int, default=1, help="corrupted streams (seeds from --seed)"
    )
    p.add_argument("--seed", type=int, default=1)
    for name in ("memory", "pty", "cpu", "robustness"):
        p.add_argument(f"--skip-{name}", action="store_true")
    args = p.parse_args(argv)
    if args.repeat < 1:
        p.error("--repeat must be at least 1")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    cmd = " ".join(["python", "bench/bench_aa55.py", *(sys.argv[1:] if argv is None else argv)])
    print(f"Command: `{cmd}`\n\nMachine: {machine()}\n")
    print(run(args))
    return 0


if __name__ == "__main__":
    sys.exit(main())
