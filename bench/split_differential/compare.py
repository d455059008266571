"""Old against new, driven alike: the classes split in issue 31 item 4, each fed the same seeded
random inputs in an old tree and in this one, everything they say compared line by line.

    git worktree add /tmp/base dc16de4        # the tree before the splits (never git stash)
    python bench/split_differential/compare.py /tmp/base [--seeds 100] [part ...]

Parts (one driver each, ``diff_<part>.py``; a driver prints one line per thing observed):

* ``core``: ScheduleCore (policy: steps, wire feedback, replies, releases, final frames);
* ``scheduler``: the Scheduler's runner and receiver turns without their threads, on a fake
  clock, a bus that refuses at times and the simulated servos answering (every observer call,
  subscriber call, event, notice, the metrics and the log lines), DroneCAN with foreign
  ArrayCommand/SafetyState/NodeStatus senders and GetNodeInfo requests (``FAM=dronecan``);
* ``codec``: the AA-55 Decoder (random frames, corruptions, truncations, chunkings, flushes);
* ``gimbal``: GimbalDevice (SET_ATTITUDE, manager commands, vehicle attitude, settings replaced
  as a PARAM_SET does, requests, periodic status);
* ``commands``: the servo commands through the MAVLink core (ACKs and backend calls);
* ``runlog``: RunLog (observer events in, files, counters and outcome out; wall times masked).

Why: each split claims "behaviour unchanged"; reading two versions finds what was moved, a
differential finds what moved differently. A part that differs prints its first differing line.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
TREE = HERE.parents[1]
PARTS = ("core", "scheduler", "codec", "gimbal", "commands", "runlog")


def drive(tree: Path, part: str, seeds: int, family: str | None) -> tuple[list[str], list[str]]:
    """The driver's lines and its log lines (paths of the tree left out) on ``tree``."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    if family:
        env["FAM"] = family
    done = subprocess.run(
        [sys.executable, str(HERE / f"diff_{part}.py"), "0", str(seeds)],
        cwd=tree,
        env=env,
        capture_output=True,
        text=True,
        timeout=1800,
        check=True,
    )
    logs = [line for line in done.stderr.splitlines() if str(tree) not in line]
    return done.stdout.splitlines(), logs


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("base", type=Path, help="a checkout of the old tree")
    parser.add_argument("parts", nargs="*", help=f"some of {', '.join(PARTS)} (default: all)")
    parser.add_argument("--seeds", type=int, default=100)
    parser.add_argument("--family", help="scheduler: one servo family (dronecan...)")
    args = parser.parse_args()
    unknown = sorted(set(args.parts) - set(PARTS))
    if unknown:
        parser.error(f"unknown parts {unknown}; the parts are {', '.join(PARTS)}")
    differing = 0
    for part in args.parts or PARTS:
        old, old_logs = drive(args.base.resolve(), part, args.seeds, args.family)
        new, new_logs = drive(TREE, part, args.seeds, args.family)
        first = next((i for i, (a, b) in enumerate(zip(old, new, strict=False)) if a != b), None)
        if first is None and len(old) == len(new) and old_logs == new_logs:
            print(f"{part}: identical ({len(new)} lines, {len(new_logs)} log lines)")
            continue
        differing += 1
        print(f"{part}: DIFFERS ({len(old)} vs {len(new)} lines)")
        if first is not None:
            print(f"  old: {old[first][:400]}\n  new: {new[first][:400]}")
        elif old_logs != new_logs:
            print("  the log lines differ")
    return 1 if differing else 0


if __name__ == "__main__":
    sys.exit(main())
