"""Promise 11: hostile YAML to `mavservo check`: exit 0 or 2 with FILE:LINE within a second,
never a traceback.

Usage: python attack/a11_yaml.py
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

MAVSERVO = str(Path(sys.executable).parent / "mavservo")
GOOD = (Path(__file__).resolve().parent / "cfg_open.yaml").read_text()


def bomb(levels: int = 9) -> str:
    lines = ['a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    prev = "a"
    for i in range(levels):
        name = chr(ord("b") + i)
        lines.append(f"{name}: &{name} [" + ",".join([f"*{prev}"] * 9) + "]")
        prev = name
    return "\n".join(lines) + "\n"


CASES: dict[str, bytes] = {
    "alias_bomb_top": bomb().encode(),
    "alias_bomb_in_servos": (GOOD.replace("servos:", bomb() + "servos:", 1)).encode(),
    "alias_bomb_as_value": (
        GOOD
        + "\nx: &x ["
        + ",".join(["1"] * 9)
        + "]\n"
        + "".join(
            f"x{i}: &x{i} [" + ",".join([f"*x{i - 1}" if i else "*x"] * 9) + "]\n" for i in range(9)
        )
    ).encode(),
    "self_reference": b"a: &a [*a]\n",
    "self_reference_map": b"mavlink: &m {url: udpin:127.0.0.1:1, x: *m}\n",
    "merge_self": b"a: &a {<<: *a}\n",
    "merge_key_bomb": (
        "a: &a {k0: 1}\n"
        + "".join(
            f"m{i}: &m{i} {{<<: [*{'a' if i == 0 else f'm{i - 1}'}], k{i + 1}: 1}}\n"
            for i in range(2000)
        )
    ).encode(),
    "deep_brackets": b"a: " + b"[" * 100_000 + b"]" * 100_000 + b"\n",
    "deep_braces": b"a: " + b"{b: " * 5000 + b"1" + b"}" * 5000 + b"\n",
    "deep_block": "".join("  " * i + f"k{i}:\n" for i in range(3000)).encode(),
    "binary_junk": os.urandom(4096),
    "nul_bytes": GOOD.encode().replace(b"servos:", b"serv\x00os:", 1),
    "utf16_bom": "\ufeffmavlink: {}\n".encode("utf-16"),
    "invalid_utf8": GOOD.encode() + b"\n# \xff\xfe\xc3\x28\n",
    "huge_file_20MB": GOOD.encode() + b"\n" + b"# padding\n" * 2_000_000,
    "huge_string": b"mavlink: {url: '" + b"A" * 20_000_000 + b"'}\n",
    "tabs": GOOD.replace("  url:", "\turl:", 1).encode(),
    "duplicate_keys": (GOOD + "\nmavlink: {url: 'udpin:0.0.0.0:1'}\n").encode(),
    "duplicate_nested": GOOD.replace("  baud: 115200", "  baud: 115200\n  baud: 9600", 1).encode(),
    "huge_int": GOOD.replace("baud: 115200", "baud: " + "9" * 100_000, 1).encode(),
    "huge_float_exp": GOOD.replace(
        "heartbeat_timeout_s: 3600", "heartbeat_timeout_s: 1e99999", 1
    ).encode(),
    "python_tag": b"a: !!python/object/apply:os.system ['echo PWNED']\n",
    "custom_tag": GOOD.replace("baud: 115200", "baud: !!binary aGVsbG8=", 1).encode(),
    "timestamp_key": b"2001-12-14t21:59:43.10-05:00: 1\n",
    "many_documents": b"---\na: 1\n" * 100_000,
    "empty": b"",
    "only_comment": b"# nothing\n",
    "sequence_top": b"- 1\n- 2\n",
    "null_top": b"~\n",
    "complex_key": b"? [a, b]\n: 1\n",
    "directive_junk": b"%YAML 9.9\n---\na: 1\n",
    "anchor_100k": ("a: [" + ",".join(f"&x{i} 1" for i in range(100_000)) + "]\n").encode(),
    "long_line_keys": ("{" + ",".join(f"k{i}: {i}" for i in range(200_000)) + "}\n").encode(),
    "nan_values": GOOD.replace(
        "heartbeat_timeout_s: 3600", "heartbeat_timeout_s: .nan", 1
    ).encode(),
    "inf_values": GOOD.replace(
        "heartbeat_timeout_s: 3600", "heartbeat_timeout_s: .inf", 1
    ).encode(),
    "yes_no_bool": GOOD.replace("tlog: true", "tlog: yes", 1).encode(),
    "key_file_dev_zero": GOOD.replace(
        "signing: null", "signing: {key_file: /dev/zero}", 1
    ).encode(),
    "key_file_fifo": b"",  # filled below
    "key_file_dir": GOOD.replace("signing: null", "signing: {key_file: /tmp}", 1).encode(),
    "replay_file_dev_zero": GOOD.replace(
        "profile: sweep", "profile: replay\n    replay_file: /dev/zero", 1
    ).encode(),
}


def main() -> None:
    tmp = Path(tempfile.mkdtemp(prefix="atk_yaml_"))
    fifo = tmp / "fifo"
    os.mkfifo(fifo)
    CASES["key_file_fifo"] = GOOD.replace(
        "signing: null", f"signing: {{key_file: {fifo}}}", 1
    ).encode()
    worst = 0.0
    problems = []
    for name, data in CASES.items():
        path = tmp / f"{name}.yaml"
        path.write_bytes(data)
        t0 = time.monotonic()
        try:
            r = subprocess.run([MAVSERVO, "check", str(path)], capture_output=True, timeout=20)
            rc, out = r.returncode, (r.stdout + r.stderr).decode(errors="replace")
        except subprocess.TimeoutExpired:
            rc, out = "TIMEOUT(20s)", ""
        dt = time.monotonic() - t0
        worst = max(worst, dt)
        has_line = f"{path}:" in out
        tb = "Traceback" in out
        ok = rc in (0, 2) and not tb and (rc == 0 or has_line) and dt < 2.0
        first = out.strip().splitlines()[0][:150] if out.strip() else ""
        print(
            f"{'ok ' if ok else 'BAD'} {name:24s} rc={rc} {dt:5.2f}s file:line={has_line} "
            f"tb={tb} | {first.replace(str(tmp) + '/', '')}"
        )
        if not ok:
            problems.append((name, rc, dt, out[-600:]))
    print(f"worst wall time {worst:.2f}s (process start ~0.5 s included)")
    for name, rc, dt, out in problems:
        print(f"--- {name} rc={rc} {dt:.2f}s\n{out}")


if __name__ == "__main__":
    main()
