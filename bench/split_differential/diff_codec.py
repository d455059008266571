"""Differential driver for the AA-55 Decoder: seeded random streams, random chunking and idle
flushes; everything it says is printed (run on the old and the new tree, compare)."""

import random

import can
from lives import print_lives

from mavservo.transport.aa55.codec import Decoder, Frame, encode, settings_frame


def show(item):
    if isinstance(item, can.Message):
        return (
            "msg",
            item.arbitration_id,
            item.is_extended_id,
            item.is_remote_frame,
            item.dlc,
            bytes(item.data).hex(),
            item.timestamp,
            item.channel,
        )
    if isinstance(item, Frame):
        return ("frame", tuple(item), item[5])
    return ("other", repr(item))


def stream(rng, protocol):
    parts = []
    for _ in range(rng.randint(1, 25)):
        a = rng.random()
        if a < 0.5:
            ext = rng.random() < 0.5
            rtr = rng.random() < 0.15
            dlc = rng.randint(0, 8)
            aid = rng.randrange(1 << 29) if ext else rng.randrange(1 << 11)
            data = bytes(rng.randrange(256) for _ in range(0 if rtr else dlc))
            fr = Frame(aid, ext, rtr, dlc, data, 0.0)
            raw = bytearray(encode(fr, protocol))
            if rng.random() < 0.15 and raw:
                raw[rng.randrange(len(raw))] ^= 1 << rng.randrange(8)
            if rng.random() < 0.1:
                raw = raw[: rng.randrange(len(raw) + 1)]
            parts.append(bytes(raw))
        elif a < 0.6:
            parts.append(settings_frame(protocol=protocol))
        elif a < 0.8:
            parts.append(
                bytes(
                    rng.choice([0xAA, 0x55, 0xC8, 0xE8, 0x00, rng.randrange(256)])
                    for _ in range(rng.randint(1, 6))
                )
            )
        else:
            parts.append(bytes(rng.randrange(256) for _ in range(rng.randint(1, 30))))
    return b"".join(parts)


def run(seed):
    rng = random.Random(seed)
    protocol = rng.choice(["variable", "fixed"])
    dec = Decoder(
        protocol,
        keep_rejections=16,
        resolve_overlaps=rng.random() < 0.8,
        messages=rng.random() < 0.3,
        channel=rng.choice([None, "c0"]),
    )
    data = stream(rng, protocol)
    out = []
    i, t = 0, 0.0
    while i < len(data):
        n = rng.choice([1, 2, 3, 7, 13, 20, 64, 1000])
        chunk = data[i : i + n]
        if rng.random() < 0.5:
            chunk = bytearray(chunk)
        i += n
        t += 0.001
        out.append(("feed", [show(x) for x in dec.feed(chunk, t)], dec.pending))
        if rng.random() < 0.1:
            out.append(("flush", [show(x) for x in dec.flush(t)], dec.pending))
    out.append(("flush", [show(x) for x in dec.flush(t)], dec.pending))
    out.append(
        (
            "counters",
            dec.frames,
            dec.settings,
            dec.control,
            dec.bytes_discarded,
            sorted((k.value, v) for k, v in dec.rejected.items()),
            [(r.value, b.hex()) for r, b in dec.rejections],
        )
    )
    return out


if __name__ == "__main__":
    print_lives(run)
