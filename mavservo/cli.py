"""The ``mavservo`` command: one entry point, one subcommand per job.

Each subcommand lives in the module that does the work and exposes ``main(argv) -> int``; this
file only dispatches, so ``mavservo --help`` stays fast and a broken optional extra (matplotlib for
``report``) cannot stop ``run``.
"""

from __future__ import annotations

import difflib
import importlib
import os
import sys
from collections.abc import Sequence
from typing import NamedTuple


class Command(NamedTuple):
    """Where a subcommand lives: ``module.function(argv) -> int``, and its one-line help.

    ``takes_prog``: the function also runs on its own (``python -m mavservo.sim.autopilot``) and
    accepts ``prog=``; it is told ``mavservo NAME`` so its usage reads ``mavservo sitl ...``, not
    ``sitl ...``. Declared here rather than discovered, so dispatch inspects nothing.
    """

    module: str
    function: str
    help: str
    takes_prog: bool = False


COMMANDS: dict[str, Command] = {
    "run": Command("mavservo.app.run", "main", "run the bridge (default: the built-in simulation)"),
    "check": Command(
        "mavservo.app.check", "check_main", "validate config files, print mapping and bus load"
    ),
    "sim": Command(
        "mavservo.sim.sim_command",
        "main",
        "USB-CAN adapter emulator with simulated servos on a pty",
    ),
    "sitl": Command(
        "mavservo.sim.autopilot.sitl_command",
        "main",
        "simulated autopilot stream, replay of a .tlog, or a built ArduPlane SITL",
        takes_prog=True,
    ),
    # gcs (issue 30): the example configs after a pip install
    "examples": Command(
        "mavservo.app.examples", "main", "write the example configs to a folder", takes_prog=True
    ),
    "monitor": Command(
        "mavservo.app.monitor", "main", "live terminal dashboard of a running bridge"
    ),
    "doctor": Command(
        "mavservo.app.doctor", "main", "read-only diagnosis of a real bus: bitrate, ids, modes"
    ),
    "params": Command(
        "mavservo.app.params_command",
        "main",
        "MAVLink parameters of a config: list, overlay, metadata",
    ),
    "report": Command(
        "mavservo.app.report", "main", "figures and a summary from a run's log directory"
    ),
}


def _usage() -> str:
    lines = ["usage: mavservo COMMAND [options]   (mavservo COMMAND --help for details)", ""]
    lines += [f"  {name:<8} {command.help}" for name, command in COMMANDS.items()]
    lines += [
        "",
        "options:",
        "  -h, --help     this help",
        "  -V, --version  print the version and exit",
        "",
        "With no command, `mavservo` is `mavservo run` on the built-in simulation.",
    ]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    try:
        return _dispatch(list(sys.argv[1:] if argv is None else argv))
    except BrokenPipeError:  # `mavservo check x.yaml | head`: the reader left, not an error
        # stdout still holds what the reader did not take: point it at /dev/null so the
        # interpreter's flush at exit does not fail on the closed pipe a second time
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


def _dispatch(args: list[str]) -> int:
    if args and args[0] in ("-h", "--help"):
        print(_usage())
        return 0
    if args and args[0] in ("-V", "--version"):
        from mavservo import __version__

        print(f"mavservo {__version__}")
        return 0
    if not args or args[0].startswith("-"):
        args = ["run", *args]
    name, rest = args[0], args[1:]
    if name not in COMMANDS:
        print(
            f"mavservo: unknown command {name!r}{_unknown_hint(name)}\n\n{_usage()}",
            file=sys.stderr,
        )
        return 2
    command = COMMANDS[name]
    try:
        module = importlib.import_module(command.module)
    except ImportError as exc:
        print(f"mavservo {name}: unavailable ({exc})", file=sys.stderr)
        return 2
    func = getattr(module, command.function)
    result = func(rest, prog=f"mavservo {name}") if command.takes_prog else func(rest)
    return int(result or 0)


def _unknown_hint(name: str) -> str:
    """What the user most likely meant: a misspelt command, or a config given without ``run``."""
    if name.endswith((".yaml", ".yml")):
        return f"; to run a config: mavservo run {name} (to check it: mavservo check {name})"
    close = difflib.get_close_matches(name, list(COMMANDS), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
