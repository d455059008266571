"""The life cycle both simulator drivers share: a thread started by ``start()``, ended by
``stop()``, waited for, and usable as a context manager (the thread itself is a
:class:`~mavservo.threads.BackgroundLoop`)."""

from __future__ import annotations

from typing import Any

from mavservo.threads import BackgroundLoop


class Background:
    """Mixin for a class that sets ``self._loop`` in ``__init__`` and defines ``start()`` and
    ``stop()`` around it."""

    _loop: BackgroundLoop

    def start(self) -> Any:  # pragma: no cover - every user defines it
        raise NotImplementedError

    def stop(self, timeout: float = 2.0) -> None:  # pragma: no cover - every user defines it
        raise NotImplementedError

    def wait(self, timeout: float) -> bool:
        """Wait for the thread to end by itself; True when it has (or never started)."""
        return self._loop.join(timeout)

    @property
    def running(self) -> bool:
        return self._loop.is_running

    def __enter__(self) -> Any:
        return self if self._loop.started else self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
