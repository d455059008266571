"""Signal dispositions for the child processes a test sends signals to.

Why: a child inherits the signals its parent *ignores* (handlers are reset by exec, SIG_IGN is
kept). Under ``nohup python -m pytest`` SIGHUP is ignored, so ``mavservo run`` rightly kept it
ignored (``nohup`` asked for that) and two SIGHUP tests waited out their timeouts; a shell runs a
background job (``pytest &``) with SIGINT and SIGQUIT ignored the same way (issue 37). A test
that sends a signal therefore starts its child with the default dispositions, as a terminal
would: ``subprocess.Popen(..., preexec_fn=default_signal_dispositions)``.

``preexec_fn`` runs between fork and exec; it only calls ``signal.signal`` (no lock another
thread could hold), so it is safe in pytest's threaded workers.
"""

from __future__ import annotations

import signal

#: the signals the tests send, or that mavservo's commands catch
SENT = ("SIGHUP", "SIGINT", "SIGTERM", "SIGQUIT", "SIGUSR1", "SIGUSR2")


def default_signal_dispositions() -> None:
    """The child starts with every signal of :data:`SENT` at its default disposition."""
    for name in SENT:
        number = getattr(signal, name, None)
        if number is not None:
            signal.signal(number, signal.SIG_DFL)


def as_under_nohup() -> None:
    """The defaults, then SIGHUP ignored: what ``nohup`` does before it starts the command."""
    default_signal_dispositions()
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
