"""Smoke test of bench/bench_aa55.py: the script runs, and its classification is right.

The benchmark is run by hand, so nothing else would notice it rotting; and a robustness table is
only worth something if the classifier behind it is correct, so that is checked on cases whose
answer is known. Behaviour only: no timing is asserted (the machines are shared and noisy).
"""

from __future__ import annotations

import importlib.util
import sys
from types import ModuleType

import pytest

from mavservo.transport.aa55.codec import Frame, encode
from tests.support.paths import REPO

BENCH = REPO / "bench" / "bench_aa55.py"


@pytest.fixture(scope="module")
def bench() -> ModuleType:
    """The bench script imported as a module (bench/ is not a package)."""
    spec = importlib.util.spec_from_file_location("bench_aa55", BENCH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["bench_aa55"] = module  # dataclasses look their module up by name
    spec.loader.exec_module(module)
    return module


def test_corrupted_stream_is_seeded_and_has_every_kind_of_damage(bench: ModuleType) -> None:
    a = bench.corrupted_stream(2000, seed=7)
    b = bench.corrupted_stream(2000, seed=7)
    assert a.stream == b.stream and a.status == b.status
    assert len(a.frames) == len(a.status) == 2000
    for state in (bench.INTACT, bench.FLIPPED, bench.TRUNCATED):
        assert state in a.status
    assert len(a.stream) > len(bench.encode_stream(a.frames)) * 0.9


def test_robustness_on_2000_frames(bench: ModuleType) -> None:
    # Seeded, so deterministic; at 100,000 frames ours loses ~0.03% (truncated-frame splices),
    # which this small stream does not contain.
    seeed, ours, fixed = bench.bench_robustness(2000, seed=3)
    assert ours.recovered_percent == 100.0 and ours.intact_lost == 0
    assert ours.recoverable_percent == 100.0
    assert ours.wrong_impossible == 0
    assert fixed.wrong == 0
    assert fixed.intact_lost == 0
    # seeedstudio reads the same stream; it must at least produce output to compare against
    assert 0 < seeed.intact_recovered <= seeed.intact == ours.intact


def test_forced_losses_are_certified_only_where_a_clean_stream_has_the_same_bytes(
    bench: ModuleType,
) -> None:
    """A frame cut after 5 bytes, then an intact 8-byte frame: 13 bytes that are a clean frame.

    Flanked by frames, the loss of the 8-byte frame is forced; with garbage after it, it is
    not (a decoder can see the damage), and our decoder then recovers it.
    """
    first = Frame(0x100, False, False, 1, b"\x01")
    cut = Frame(0x101, False, False, 8, bytes(8))
    real = Frame(0x202, False, False, 3, b"\x01\x02\x03")
    after = Frame(0x303, False, False, 1, b"\x01")
    states = [bench.INTACT, bench.TRUNCATED, bench.INTACT, bench.INTACT]
    for garbage, forced in ((b"", 1), (b"\x07", 0)):
        parts = [encode(first), encode(cut)[:5], encode(real) + garbage, encode(after)]
        offsets = [sum(len(p) for p in parts[:i]) for i in range(4)]
        truth = bench.Corrupted(b"".join(parts), [first, cut, real, after], states, offsets)
        outputs = [f.key() for f in bench.ours_on_bytes(truth.stream)]
        r = bench.classify("t", truth, outputs, None, truth.stream)
        assert (r.intact_lost, r.lost_forced) == ((1, 1) if forced else (0, 0))
        assert r.recoverable_percent == 100.0
    # the certificate itself, on a loss our decoder avoids: the outer frame followed by garbage
    outer = Frame(0x101, False, False, 8, b"\x00" + encode(real)[:-1])
    outputs = [first.key(), outer.key(), after.key()]
    assert bench.forced_losses(truth, outputs, [2]) == []
    flanked = bench.Corrupted(
        truth.stream.replace(b"\x07", b""), truth.frames, states, offsets[:3] + [offsets[3] - 1]
    )
    assert bench.forced_losses(flanked, outputs, [2]) == [2]


def test_classifier_counts_known_cases(bench: ModuleType) -> None:
    """Hand-made outputs: one recovered, one flipped payload, one impossible, one bad type."""
    sent = [Frame(0x100 + i, False, False, 2, bytes((i, i))) for i in range(3)]
    stream = bench.encode_stream(sent)
    truth = bench.Corrupted(stream, sent, [bench.INTACT, bench.FLIPPED, bench.INTACT])
    flipped = (0x101, False, False, 2, b"\x01\x02")  # valid structure; bytes put in the stream
    impossible = (0x900, False, False, 2, b"\x00\x00")  # standard ID out of range
    stream += encode(Frame(*flipped))
    outputs = [sent[0].key(), flipped, impossible]
    r = bench.classify("t", truth, outputs, None, stream)
    assert (r.intact_recovered, r.intact_lost) == (1, 1)
    assert (r.wrong_undetectable, r.wrong_impossible) == (1, 1)
    # a frame the decoder read through a bad type byte (0x08 instead of 0xC8): impossible
    raw = b"\xaa\x08" + bytes(4) + b"\x55"
    bad_type = (0, False, False, 8, bytes(8))
    assert bench.is_impossible(bad_type, stream, raw)
    assert not bench.is_impossible(sent[2].key(), stream, encode(sent[2]))


def test_both_decoders_read_the_clean_stream_in_memory(bench: ModuleType) -> None:
    frames = bench.throughput_frames(2000, seed=1)
    stream = bench.encode_stream(frames)
    assert bench.seeed_count(stream) == 2000
    assert bench.ours_on_bytes(stream) == frames
    assert len(bench.ours_messages(stream)) == 2000
    assert bench.ours_count(stream) == bench.ours_count(stream, to_message=True) == 2000
    rates = bench.bench_memory(stream)
    assert set(rates) == {"seeed", "ours", "ours_msg"} and all(v > 0 for v in rates.values())


@pytest.mark.parametrize("kind", ["aa55", "seeedstudio"])
def test_pty_run_delivers_every_frame(bench: ModuleType, kind: str) -> None:
    frames = bench.throughput_frames(2000, seed=2)
    result = bench.run_pty(kind, bench.encode_stream(frames), len(frames), keep_keys=True)
    sent = [f.key() for f in frames]
    assert result.keys == sent  # every frame, in order, nothing invented
    it = iter(sent)
    assert all(any(k == s for s in it) for k in result.keys)
    assert result.init_bytes == 20  # the settings / init frame was drained from the master


def test_paced_pty_run_reports_cpu(bench: ModuleType) -> None:
    frames = bench.throughput_frames(300, seed=4)
    result = bench.run_pty("aa55", bench.encode_stream(frames), len(frames), fps=3000)
    assert result.frames == 300
    assert 0.0 <= result.cpu <= result.wall * 1.5 + 0.05


def test_main_prints_a_markdown_table(bench: ModuleType, capsys: pytest.CaptureFixture) -> None:
    argv = ["--repeat", "1", "--frames", "500", "--skip-pty", "--skip-cpu"]
    assert bench.main([*argv, "--robust-frames", "500"]) == 0
    out = capsys.readouterr().out
    assert "| measurement | seeedstudio | aa55 (ours) |" in out
    assert "| aa55 (ours), fixed protocol |" in out
    assert "of which forced" in out
    assert "Machine: " in out


def test_receive_cost_is_measured_over_every_frame(bench: ModuleType) -> None:
    stream = bench.encode_stream(bench.throughput_frames(600, seed=4))
    assert bench.receive_cost_per_frame(stream, pause=0.0) > 0
