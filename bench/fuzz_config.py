"""Hostile config files against ``mavservo check``: count tracebacks, hangs and line-less errors.

Each input is written to a file and checked by ``check_main`` in its own Python process (so a
hang is a timeout, not a stalled bench), which prints its exit status and the CPU time of the
check (CPU, not wall: on a loaded 2-core machine wall time measures the neighbours). An input
passes when it ends in exit 0, or in exit 2 with the first error line starting ``FILE:LINE:``,
without a traceback, within ``--timeout`` seconds of wall time.

Inputs: the shipped configs mutated (byte flips, lines deleted, duplicated, re-indented,
truncated, YAML syntax spliced in, values swapped for wrong types), and generated hostile
documents (alias bombs of 2-12 levels, self-referencing aliases and merge keys, 10-100,000
nested brackets or block levels, binary junk, NUL and control bytes, invalid UTF-8, 1-50 MB
scalars, 100,000 keys, unknown tags, several documents). Seeded: the same ``--seed`` and
``--count`` try the same inputs. Run by hand::

    python bench/fuzz_config.py --count 300 --seed 1
    python bench/fuzz_config.py --count 300 --seed 1 --code /tmp/old   # a baseline
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import subprocess
import sys
import tempfile
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SEEDS = sorted((ROOT / "config").glob("*.yaml"))

CHILD = r"""
import sys, time
from mavservo.app.check import check_main
import io
t = time.process_time()
err = io.StringIO()
rc = check_main([sys.argv[1]], out=io.StringIO(), err=err)
print("RESULT", rc, time.process_time() - t, flush=True)
sys.stderr.write(err.getvalue())
"""

SPLICES = [
    "&a ",
    "*a",
    "*zz",
    "[",
    "]",
    "{",
    "}",
    "<<: *a",
    "? ",
    "!!python/object:os.system ",
    "!!binary ",
    "!!set ",
    "!!omap ",
    "!custom ",
    "- ",
    ": ",
    "'",
    '"',
    "\t",
    "\x00",
    "\x1b",
    "---\n",
    "...\n",
    "%YAML 1.1\n",
    "#",
    "|",
    ">",
    "~",
    "null",
    "yes",
    "1e999",
    "-0x10",
    "2024-01-01",
    "\ufeff",
    "\u202e",
    "&b [*b]",
    "{a: 1, a: 2}",
]
WRONG_VALUES = [
    "[]",
    "{}",
    "null",
    "yes",
    "-1",
    "1e309",
    "nan",
    ".inf",
    "'12'",
    "[1, 2, [3]]",
    "{x: {y: {z: 1}}}",
    "0x7FFFFFFFFFFFFFFFFF",
    "''",
    "!!binary AAAA",
    "2001-01-01",
    "*a",
]


def alias_bomb(levels: int, width: int = 9) -> str:
    lines = ["l0: &l0 [" + ", ".join(["lol"] * width) + "]"]
    for level in range(1, levels + 1):
        lines.append(f"l{level}: &l{level} [" + ", ".join([f"*l{level - 1}"] * width) + "]")
    return "\n".join(lines) + f"\nservos: *l{levels}\n"


def generated(rng: random.Random) -> bytes:
    kind = rng.randrange(14)
    if kind == 0:
        return alias_bomb(rng.randint(2, 12), rng.randint(2, 12)).encode()
    if kind == 1:
        return rng.choice(
            [b"a: &x [*x]\n", b"a: &x {b: *x}\n", b"a: &x {<<: *x}\n", b"servos: &s [{x: *s}]\n"]
        )
    if kind == 2:
        n = rng.choice([10, 100, 1000, 10_000, 100_000])
        return b"servos: " + b"[" * n + b"]" * n + b"\n"
    if kind == 3:
        n = rng.choice([40, 200, 1000])
        return "".join(" " * i + f"k{i}:\n" for i in range(n)).encode()
    if kind == 4:
        return rng.randbytes(rng.choice([10, 1000, 100_000]))
    if kind == 5:
        return b"servos:\n  - name: " + b"x" * rng.choice([10**6, 10**7, 5 * 10**7]) + b"\n"
    if kind == 6:
        return ("".join(f"k{i}: {i}\n" for i in range(rng.choice([1000, 100_000])))).encode()
    if kind == 7:
        return b"servos: !!python/object/apply:os.system ['true']\n"
    if kind == 8:
        return b"a: 1\n---\nb: 2\n"
    if kind == 9:
        return b"servos:\n  - name: \xff\xfe\x00bad\n"
    if kind == 10:
        return b"servos: [" + b"{a: " * 500 + b"1" + b"}" * 500 + b"]\n"
    if kind == 11:
        return b"? [a, b]\n: 1\n? {c: d}\n: 2\nservos: []\n"
    if kind == 12:
        return ("x: " + "&a " * 3 + "1\n").encode()
    return b"\x00" * rng.randint(1, 100)


def mutated(rng: random.Random) -> bytes:
    text = rng.choice(SEEDS).read_text(encoding="utf-8")
    lines = text.splitlines(keepends=True)
    for _ in range(rng.randint(1, 6)):
        if not lines:
            break
        i = rng.randrange(len(lines))
        op = rng.randrange(7)
        if op == 0:
            del lines[i]
        elif op == 1:
            lines.insert(i, lines[i])
        elif op == 2:
            lines[i] = " " * rng.randint(1, 6) + lines[i]
        elif op == 3:
            pos = rng.randint(0, len(lines[i]))
            lines[i] = lines[i][:pos] + rng.choice(SPLICES) + lines[i][pos:]
        elif op == 4 and ":" in lines[i]:
            key = lines[i].split(":", 1)[0]
            lines[i] = f"{key}: {rng.choice(WRONG_VALUES)}\n"
        elif op == 5:
            lines = lines[:i]
        else:
            data = bytearray(lines[i].encode())
            if data:
                data[rng.randrange(len(data))] = rng.randrange(256)
            lines[i] = data.decode("latin-1")
    return "".join(lines).encode("utf-8", "surrogateescape")


def check(path: Path, timeout: float, code: Path) -> dict[str, object]:
    started = time.perf_counter()
    env = dict(os.environ, PYTHONPATH=str(code))
    try:
        proc = subprocess.run(
            [sys.executable, "-c", CHILD, str(path)],
            capture_output=True,
            text=True,
            timeout=timeout,
            cwd=code,
            env=env,
        )
    except subprocess.TimeoutExpired:
        return {"outcome": "hang", "wall_s": time.perf_counter() - started}
    match = re.search(r"^RESULT (\d+) ([\d.e-]+)$", proc.stdout, re.M)
    if "Traceback" in proc.stderr or match is None:
        return {"outcome": "traceback", "stderr": proc.stderr[-2000:]}
    rc, seconds = int(match.group(1)), float(match.group(2))
    errors = [line for line in proc.stderr.splitlines() if line.strip()]
    pattern = re.compile(rf"^{re.escape(str(path))}:\d+: ")
    if rc == 2 and (not errors or not pattern.match(errors[0])):
        return {"outcome": "no-line", "rc": rc, "check_s": seconds, "stderr": proc.stderr[:500]}
    if rc not in (0, 2):
        return {"outcome": f"exit-{rc}", "check_s": seconds}
    return {"outcome": f"exit-{rc}", "check_s": seconds}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=300)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--timeout", type=float, default=30.0)
    parser.add_argument("--keep", help="directory to keep failing inputs in")
    parser.add_argument(
        "--code",
        type=Path,
        default=ROOT,
        help="checkout whose mavservo to test (a baseline: git archive OLD | tar -x -C DIR)",
    )
    args = parser.parse_args()
    rng = random.Random(args.seed)
    inputs = [(generated if i % 3 == 0 else mutated)(rng) for i in range(args.count)]
    with tempfile.TemporaryDirectory() as tmp:
        paths = []
        for i, data in enumerate(inputs):
            path = Path(tmp) / f"in{i:04d}.yaml"
            path.write_bytes(data)
            paths.append(path)
        with ThreadPoolExecutor(args.jobs) as pool:
            results = list(pool.map(lambda p: check(p, args.timeout, args.code), paths))
        outcomes = Counter(str(r["outcome"]) for r in results)
        times = sorted(float(r["check_s"]) for r in results if "check_s" in r)
        bad = [
            (p, r)
            for p, r in zip(paths, results, strict=True)
            if r["outcome"] not in ("exit-0", "exit-2")
        ]
        if args.keep:
            keep = Path(args.keep)
            keep.mkdir(parents=True, exist_ok=True)
            for p, _ in bad:
                (keep / p.name).write_bytes(p.read_bytes())
    for p, r in bad[:10]:
        print(p.name, json.dumps(r)[:600])
    summary = {
        "inputs": args.count,
        "seed": args.seed,
        "outcomes": dict(outcomes),
        "tracebacks": outcomes["traceback"],
        "hangs": outcomes["hang"],
        "check_s_median": times[len(times) // 2] if times else None,
        "check_s_max": times[-1] if times else None,
    }
    print(json.dumps(summary, indent=2))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
