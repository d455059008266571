"""The life cycle both simulator drivers share: a thread started by ``start()``, ended by
``stop()``, waited for, and usable as a context manager."""

from __future__ import annotations

import threading
from typing import Any


class Background:
    """Mixin for a class that sets ``self._thread`` in ``start()`` and defines ``stop()``."""

    _thread: threading.Thread | None

    def start(self) -> Any:  # pragma: no cover - every user defines it
        raise NotImplementedError

    def stop(self, timeout: float = 2.0) -> None:  # pragma: no cover - every user defines it
        raise NotImplementedError

    def wait(self, timeout: float) -> bool:
        """Wait for the thread to end by itself; True when it has (or never started)."""
        if self._thread is None:
            return True
        self._thread.join(timeout)
        return not self._thread.is_alive()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def __enter__(self) -> Any:
        return self if self._thread is not None else self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
