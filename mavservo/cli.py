"""The ``mavservo`` command: one entry point, one subcommand per job.

Each subcommand lives in the module that does the work and exposes ``main(argv) -> int``; this
file only dispatches, so ``mavservo --help`` stays fast and a broken optional extra (matplotlib for
``report``) cannot stop ``run``.
"""

from __future__ import annotations

import importlib
import inspect
import os
import sys
from collections.abc import Callable, Sequence
from typing import Any

#: subcommand -> (module, function, one-line help)
COMMANDS: dict[str, tuple[str, str, str]] = {
    "run": ("mavservo.runcmd", "main", "run the bridge (default: the built-in simulation)"),
    "check": ("mavservo.config", "check_main", "validate config files, print mapping and bus load"),
    "sim": ("mavservo.sim.cli", "main", "USB-CAN adapter emulator with simulated servos on a pty"),
    "sitl": ("sitl.cli", "main", "simulated autopilot stream, or replay of a .tlog"),
    "monitor": ("mavservo.monitor", "main", "live terminal dashboard of a running bridge"),
    "report": ("mavservo.report", "main", "figures and a summary from a run's log directory"),
}


def _usage() -> str:
    lines = ["usage: mavservo COMMAND [options]   (mavservo COMMAND --help for details)", ""]
    lines += [f"  {name:<8} {help_}" for name, (_, _, help_) in COMMANDS.items()]
    lines += ["", "With no command, `mavservo` is `mavservo run` on the built-in simulation."]
    return "\n".join(lines)


def _call(func: Callable[..., Any], argv: list[str], name: str) -> Any:
    """Run a subcommand; one that also runs on its own (``python -m sitl``) and takes ``prog``
    is told its name here, so its usage reads ``mavservo sitl ...``, not ``sitl ...``."""
    if "prog" in inspect.signature(func).parameters:
        return func(argv, prog=f"mavservo {name}")
    return func(argv)


def main(argv: Sequence[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
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
        print(f"mavservo: unknown command {name!r}\n\n{_usage()}", file=sys.stderr)
        return 2
    module_name, func_name, _ = COMMANDS[name]
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        print(f"mavservo {name}: unavailable ({exc})", file=sys.stderr)
        return 2
    try:
        result = _call(getattr(module, func_name), rest, name)
    except BrokenPipeError:  # `mavservo check x.yaml | head`: the reader left, not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    return int(result or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
