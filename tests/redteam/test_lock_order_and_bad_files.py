"""Red-team findings D, E, F (attack/README.md): each test fails on the code before the fix.

D: ServoBackend called its event hook (which announces over MAVLink, taking the MAVLink side's
lock) with its own lock held, while MAVLink threads hold that lock and call into the backend.
E: a constructor failure (a 4,301-digit integer, a bad !!timestamp) was a traceback.
F: key_file and the config path were read without bound and with a blocking open.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

import pytest

from mavservo.config import load_config_text
from mavservo.config.loader import ConfigError, load_config
from mavservo.config.schema import read_key_file
from mavservo.control.servo_backend import ServoBackend
from tests.control.test_servo_backend import CONFIG, RecordingSink

WAIT_S = 5.0


def _backend_with_pending_slew(on_event) -> tuple[ServoBackend, RecordingSink]:
    config = load_config_text(CONFIG, "backend.yaml")
    sink = RecordingSink()
    backend = ServoBackend(config, {s.name: sink for s in config.servos}, on_event=on_event)
    assert backend.apply_servo_output(3, 1000, "test", 0.0).ok
    assert backend.apply_servo_output(3, 2000, "test", 0.01).ok  # slew-limited: goal pending
    sink.offline.add("throttle")
    return backend, sink


def test_offline_event_is_emitted_without_the_backend_lock_held() -> None:
    """The D cycle with two threads: the hook takes ``other`` (the MAVLink side's lock) while
    another thread holds ``other`` and asks the backend for statuses. Bounded by timeouts: on
    the old code the hook cannot get ``other`` and the test fails instead of hanging."""
    other = threading.Lock()
    hook_entered, other_held = threading.Event(), threading.Event()
    hook_got_lock: list[bool] = []

    def hook(line: str) -> None:
        hook_entered.set()
        other_held.wait(WAIT_S)
        got = other.acquire(timeout=WAIT_S)
        hook_got_lock.append(got)
        if got:
            other.release()

    backend, _ = _backend_with_pending_slew(hook)

    def mavlink_thread() -> None:
        assert hook_entered.wait(WAIT_S)
        with other:
            other_held.set()
            backend.servo_statuses()

    tick = threading.Thread(target=backend.tick, args=(0.5,), daemon=True)
    rx = threading.Thread(target=mavlink_thread, daemon=True)
    tick.start()
    rx.start()
    tick.join(3 * WAIT_S)
    rx.join(3 * WAIT_S)
    assert not tick.is_alive() and not rx.is_alive()
    assert hook_got_lock == [True]


def test_offline_event_still_reported_once() -> None:
    events: list[str] = []
    backend, _ = _backend_with_pending_slew(events.append)
    backend.tick(0.5)
    backend.tick(0.6)
    assert len([e for e in events if "throttle offline" in e]) == 1


def test_command_hook_runs_without_the_backend_lock_held() -> None:
    config = load_config_text(CONFIG, "backend.yaml")
    sink = RecordingSink()
    held: list[bool] = []
    backend: ServoBackend

    def on_command(servo: str, t: float) -> None:
        held.append(_held_by_other_thread(backend))

    backend = ServoBackend(
        config,
        {s.name: sink for s in config.servos},
        on_event=lambda _: None,
        on_command=on_command,
    )
    assert backend.apply_servo_output(1, 1500, "test", 0.0).ok
    assert held == [False]


def _held_by_other_thread(backend: ServoBackend) -> bool:
    """Whether this thread holds the backend's RLock (an RLock's owner can re-enter: probe from
    another thread, which can take it only when nobody holds it)."""
    result: list[bool] = []

    def probe() -> None:
        got = backend._lock.acquire(timeout=1.0)
        result.append(not got)
        if got:
            backend._lock.release()

    thread = threading.Thread(target=probe, daemon=True)
    thread.start()
    thread.join(WAIT_S)
    return result == [True]


# ------------------------------------------------------------------------------------ E


@pytest.mark.parametrize(
    ("text", "line", "words"),
    [
        ("system_id: 1\na: " + "9" * 4301 + "\n", 2, "4300 digits"),
        ("system_id: 1\n\nb: !!timestamp 2020-13-45\n", 3, "month"),
        ("a: !!python/object/apply:os.system [ls]\n", 1, "python"),
    ],
)
def test_constructor_failures_are_config_errors_with_the_line(
    text: str, line: int, words: str
) -> None:
    with pytest.raises(ConfigError) as info:
        load_config_text(text, "x.yaml")
    message = str(info.value)
    assert f"x.yaml:{line}:" in message
    assert words in message


# ------------------------------------------------------------------------------------ F


def _signed_config(key_file: str) -> str:
    return CONFIG.replace(
        'mavlink: {url: "udpin:127.0.0.1:14599"}',
        f'mavlink: {{url: "udpin:127.0.0.1:14599", signing: {{key_file: "{key_file}"}}}}',
    )


@pytest.mark.parametrize("kind", ["device", "fifo", "directory", "large"])
def test_key_file_must_be_a_small_regular_file(tmp_path: Path, kind: str) -> None:
    path = {"device": "/dev/zero", "directory": str(tmp_path)}.get(kind, str(tmp_path / "k"))
    if kind == "fifo":
        os.mkfifo(path)
    if kind == "large":
        Path(path).write_text("0" * 64 + " " * 10_000)
    result: list[BaseException] = []

    def load() -> None:
        try:
            load_config_text(_signed_config(path), str(tmp_path / "c.yaml"))
        except BaseException as exc:  # noqa: BLE001 - handed to the test thread
            result.append(exc)

    thread = threading.Thread(target=load, daemon=True)  # a FIFO hung the old code
    thread.start()
    thread.join(WAIT_S)
    assert not thread.is_alive()
    assert len(result) == 1 and isinstance(result[0], ConfigError)
    assert "key_file" in str(result[0]) and "c.yaml:2:" in str(result[0])
    with pytest.raises(ValueError):
        read_key_file(path)  # a FIFO is refused by the non-blocking open, never waited on


def test_good_key_file_still_works(tmp_path: Path) -> None:
    key = tmp_path / "k"
    key.write_text("ab" * 32 + "\n")
    config = load_config_text(_signed_config(str(key)), str(tmp_path / "c.yaml"))
    assert config.mavlink.signing is not None
    assert config.mavlink.signing.secret_key() == bytes.fromhex("ab" * 32)
    assert read_key_file(key) == bytes.fromhex("ab" * 32)


@pytest.mark.parametrize("kind", ["device", "fifo"])
def test_config_path_must_be_a_regular_file(tmp_path: Path, kind: str) -> None:
    path = "/dev/zero" if kind == "device" else str(tmp_path / "cfg")
    if kind == "fifo":
        os.mkfifo(path)
    result: list[BaseException] = []

    def load() -> None:
        try:
            load_config(path)
        except BaseException as exc:  # noqa: BLE001
            result.append(exc)

    thread = threading.Thread(target=load, daemon=True)
    thread.start()
    thread.join(WAIT_S)
    assert not thread.is_alive()
    assert len(result) == 1 and isinstance(result[0], ConfigError)
    assert "not a regular file" in str(result[0])
