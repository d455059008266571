"""CPU cost of the link's MAVLink parser on hostile and clean input (docs/engineering/security.md).

``FrameScanner`` (mavservo/mavlink/framing.py) as a datagram and as a stream, against
pymavlink's ``parse_buffer`` (the parser the link used before), on 65,000-byte buffers of
crafted candidates and on 1,000 valid frames. Median of ``--runs`` runs, milliseconds.

    python bench/bench_link_parser.py [--runs 5]
"""

from __future__ import annotations

import argparse
import os
import random
import statistics
import time
from collections.abc import Callable

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.mavlink.framing import FrameScanner

SIZE = 65_000


def inputs() -> dict[str, bytes]:
    encoder = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    clean = b"".join(
        bytes(encoder.servo_output_raw_encode(0, 0, *[1500] * 8).pack(encoder)) for _ in range(1000)
    )
    zero_frames = b"\xfd" + bytes(11)
    return {
        "FE 00 repeated": b"\xfe\x00" * (SIZE // 2),
        "FD repeated": b"\xfd" * SIZE,
        "12-byte zero-length frames, bad CRC": zero_frames * (SIZE // len(zero_frames)),
        "random bytes": random.Random(1).randbytes(SIZE),
        "1,000 valid SERVO_OUTPUT_RAW": clean,
    }


def timed(parse: Callable[[], object], runs: int) -> float:
    samples = []
    for _ in range(runs):
        start = time.perf_counter()
        parse()
        samples.append(time.perf_counter() - start)
    return statistics.median(samples) * 1000


def pymavlink_parse(data: bytes) -> object:
    decoder = mavlink2.MAVLink(None)
    decoder.robust_parsing = True
    return decoder.parse_buffer(data)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    print(f"pid {os.getpid()}, median of {args.runs} runs, ms")
    print(f"  {'input':<38} {'datagram':>9} {'stream':>8} {'pymavlink':>10}")
    for name, data in inputs().items():
        datagram = timed(lambda d=data: FrameScanner(mavlink2.MAVLink(None)).datagram(d), args.runs)
        stream = timed(lambda d=data: FrameScanner(mavlink2.MAVLink(None)).stream(d), args.runs)
        before = timed(lambda d=data: pymavlink_parse(d), args.runs)
        print(f"  {name:<38} {datagram:9.1f} {stream:8.1f} {before:10.1f}")


if __name__ == "__main__":
    main()
