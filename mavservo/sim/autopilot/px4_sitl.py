"""``mavservo sitl px4``: run a PX4 SITL binary the user already built, SIH airframe, headless.

Like ``mavservo sitl arduplane`` it never builds, fetches or runs PX4's make targets: it finds
``build/px4_sitl_default/bin/px4`` under ``--px4-home`` / ``$PX4_HOME`` (else ``px4`` on PATH,
whose ``../etc`` is the ROMFS), and runs it as PX4's own SITL start does
(``PX4_SYS_AUTOSTART``, ``PX4_SIMULATOR=sihsim``, ``PX4_SIM_MODEL``; ``px4 -d -w WORKDIR
ROMFS``: ``-d`` no shell, so it reads nothing from its standard input). SIH (simulation in
hardware) needs no external simulator; airframe 10041 is the SIH airplane.

The bridge goes on PX4's onboard (API) link: PX4 binds UDP 14580 and sends to 127.0.0.1:14540
(``ROMFS/px4fmu_common/init.d-posix/px4-rc.mavlink``: ``mavlink start -x -u 14580 -r 4000000 -f
-m onboard -o 14540``), so the bridge listens with ``mavlink.url: udpin:127.0.0.1:14540``;
QGroundControl finds PX4's GCS link by itself (PX4 binds 18570, sends to 14550).

Parameters: PX4's posix start script sources ``px4-rc.simulator`` through ``PATH`` before it
starts the gimbal module (``init.d-posix/rcS``), so the launcher puts a ``px4-rc.simulator`` of
its own first in ``PATH`` (in the work directory) that sets the companion's parameters
(:data:`COMPANION_PARAMS`, plus ``--param NAME=VALUE``) and then sources PX4's own. They are
saved in the work directory's ``parameters.bson`` like any ``param set``. ``--no-companion-params``
leaves PX4's defaults.

One PX4 instance 0 per machine (it takes a lock file ``px4_lock-0`` in the temp directory), and
its listeners bind every address: run it in a network namespace with only ``lo`` for tests.
"""

from __future__ import annotations

import argparse
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

#: SIH airframes of PX4's posix ROMFS (``init.d-posix/airframes``): number -> model name.
SIH_AIRFRAMES = {10040: "sihsim_quadx", 10041: "sihsim_airplane", 10043: "sihsim_standard_vtol"}
DEFAULT_AIRFRAME = 10041
#: PX4's onboard link: it binds 14580 and sends to this port (px4-rc.mavlink, instance 0).
ONBOARD_REMOTE_PORT = 14540
ONBOARD_LOCAL_PORT = 14580
#: Parameters a companion with servos and a gimbal needs (docs/px4.md says why each):
#: the gimbal manager on (MAVLink gimbal protocol v2 in and out), outputs active while
#: disarmed (prearm "Always": DO_SET_ACTUATOR's peripherals move on the ground), and outputs 5
#: and 6 as "Peripheral via Actuator Set 1/2" (301, 302).
COMPANION_PARAMS: dict[str, str] = {
    "MNT_MODE_IN": "4",
    "MNT_MODE_OUT": "2",
    "COM_PREARM_MODE": "2",
    "PWM_MAIN_FUNC5": "301",
    "PWM_MAIN_FUNC6": "302",
}
BUILD_BINARY = Path("build") / "px4_sitl_default" / "bin" / "px4"
EXIT_NOT_BUILT = 3
EXIT_USAGE = 2


@dataclass(frozen=True)
class Px4Command:
    """What to run: argv, the environment's additions, the work directory."""

    argv: list[str]
    env: dict[str, str]
    workdir: Path

    def shell_text(self) -> str:
        """The command as a shell line (PATH shown as the shim's folder before ``$PATH``)."""
        env = " ".join(
            f"PATH={shlex.quote(v.split(os.pathsep, 1)[0])}:$PATH"
            if k == "PATH"
            else f"{k}={shlex.quote(v)}"
            for k, v in self.env.items()
        )
        return f"cd {shlex.quote(str(self.workdir))} && {env} {shlex.join(self.argv)}"


def find_px4(px4_home: str | None) -> tuple[Path, Path] | None:
    """(binary, ROMFS etc directory) of a built PX4 SITL, or None."""
    candidates: list[Path] = []
    if px4_home:
        candidates.append(Path(px4_home) / BUILD_BINARY)
    on_path = shutil.which("px4")
    if on_path:
        candidates.append(Path(on_path))
    for binary in candidates:
        etc = binary.resolve().parent.parent / "etc"
        if binary.is_file() and os.access(binary, os.X_OK) and (etc / "init.d-posix").is_dir():
            return binary, etc
    return None


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mavservo sitl px4",
        description="Run a PX4 SITL binary already built (SIH, headless) with the bridge's "
        "parameters; the bridge listens on udpin:127.0.0.1:14540 (PX4's onboard link). Never "
        "builds or fetches PX4.",
    )
    parser.add_argument(
        "--px4-home",
        default=os.environ.get("PX4_HOME"),
        help="the PX4-Autopilot tree with build/px4_sitl_default (default: $PX4_HOME, else px4 "
        "on PATH)",
    )
    parser.add_argument(
        "--airframe",
        type=int,
        default=DEFAULT_AIRFRAME,
        choices=sorted(SIH_AIRFRAMES),
        help="SIH airframe (default: %(default)s, the airplane)",
    )
    parser.add_argument(
        "--workdir",
        type=Path,
        default=None,
        help="PX4's working directory (parameters, logs); default: a new temporary one",
    )
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="set a PX4 parameter at start (repeatable; after the companion's)",
    )
    parser.add_argument(
        "--no-companion-params",
        action="store_true",
        help="do not set the companion's parameters (gimbal manager, prearm, peripherals)",
    )
    parser.add_argument(
        "--dry-run", action="store_true", help="print the command and the parameters, run nothing"
    )
    return parser


def px4_command(
    binary: Path, etc: Path, airframe: int, workdir: Path, params: dict[str, str]
) -> Px4Command:
    """The command PX4's SITL start runs for ``airframe``, with the parameter shim on PATH."""
    env = {
        "PX4_SYS_AUTOSTART": str(airframe),
        "PX4_SIMULATOR": "sihsim",
        "PX4_SIM_MODEL": SIH_AIRFRAMES[airframe],
    }
    if params:
        env["PATH"] = f"{workdir / 'mavservo-rc'}{os.pathsep}{os.environ.get('PATH', '')}"
    return Px4Command([str(binary), "-d", "-w", str(workdir), str(etc)], env, workdir)


def write_param_shim(workdir: Path, params: dict[str, str]) -> Path:
    """``px4-rc.simulator`` that sets ``params`` and then sources PX4's own (see module doc)."""
    folder = workdir / "mavservo-rc"
    folder.mkdir(parents=True, exist_ok=True)
    shim = folder / "px4-rc.simulator"
    lines = ["#!/bin/sh", "# written by mavservo sitl px4: the companion's parameters"]
    lines += [f"param set {name} {value}" for name, value in params.items()]
    lines.append('. "${R}etc/init.d-posix/px4-rc.simulator"')
    shim.write_text("\n".join(lines) + "\n")
    return shim


def _params(args: argparse.Namespace) -> dict[str, str] | str:
    params = {} if args.no_companion_params else dict(COMPANION_PARAMS)
    for item in args.param:
        name, sep, value = item.partition("=")
        if not sep or not name.isidentifier() or not value or " " in value:
            return f"bad --param {item!r}: expected NAME=VALUE"
        params[name.upper()] = value
    return params


def run_px4(argv: Sequence[str]) -> int:
    """``mavservo sitl px4 ...``: 0 after a dry run, 3 without a built PX4, else PX4's status
    (the process is replaced by PX4, so signals reach it: SIGTERM stops it, status 0)."""
    args = build_parser().parse_args(list(argv))
    params = _params(args)
    if isinstance(params, str):
        print(f"mavservo sitl px4: {params}", file=sys.stderr)
        return EXIT_USAGE
    found = find_px4(args.px4_home)
    if args.workdir is not None:
        workdir = args.workdir
    elif args.dry_run:  # a dry run creates nothing
        workdir = Path(tempfile.gettempdir()) / "mavservo-px4-WORKDIR"
    else:
        workdir = Path(tempfile.mkdtemp(prefix="mavservo-px4-"))
    if found is None:
        where = args.px4_home or "$PX4_HOME (unset)"
        print(
            f"mavservo sitl px4: PX4 SITL is not built: no {BUILD_BINARY} under {where} and no "
            "px4 on PATH. Build it yourself, once (`make px4_sitl_default` in a PX4-Autopilot "
            "tree; docs/px4.md), then set PX4_HOME. This command never builds nor downloads "
            "anything.",
            file=sys.stderr,
        )
        if not args.dry_run:
            return EXIT_NOT_BUILT
        home = Path(args.px4_home or "PX4_HOME")
        found = (home / BUILD_BINARY, home / BUILD_BINARY.parent.parent / "etc")
    command = px4_command(found[0], found[1], args.airframe, workdir, params)
    if args.dry_run:
        print(command.shell_text())
        for name, value in params.items():
            print(f"param set {name} {value}")
        return 0
    workdir.mkdir(parents=True, exist_ok=True)
    if params:
        write_param_shim(workdir, params)
    print(
        f"mavservo sitl px4: airframe {args.airframe} ({SIH_AIRFRAMES[args.airframe]}) in "
        f"{workdir}; bridge: mavlink.url udpin:127.0.0.1:{ONBOARD_REMOTE_PORT} (PX4's onboard "
        f"link from its port {ONBOARD_LOCAL_PORT}); config/px4-sitl.yaml",
        file=sys.stderr,
        flush=True,
    )
    os.chdir(workdir)
    stdin = os.open(os.devnull, os.O_RDONLY)
    os.dup2(stdin, 0)
    os.execve(command.argv[0], command.argv, {**os.environ, **command.env})
    return 0  # not reached


def telemetry_status(bin_dir: Path, instances: int = 5) -> dict[int, dict[str, str]]:
    """PX4's own account of each running MAVLink instance (the uORB topic telemetry_status,
    ``px4-listener telemetry_status -i N`` from the binary's folder): mode, data rate, and what
    it received and lost. ``rx_message_lost_count`` counts sequence gaps, so a frame its parser
    dropped as unknown shows there. The bridge's link in SITL is the onboard instance (mode 2)
    at 4,000,000 B/s."""
    out: dict[int, dict[str, str]] = {}
    for instance in range(instances):
        done = subprocess.run(
            [str(bin_dir / "px4-listener"), "telemetry_status", "-n", "1", "-i", str(instance)],
            capture_output=True,
            text=True,
            timeout=20,
            check=False,
        )
        fields = dict(re.findall(r"^\s+(\w+): (\S+)", done.stdout, re.MULTILINE))
        if "rx_message_count" in fields:
            out[instance] = fields
    return out


def onboard_link(status: dict[int, dict[str, str]]) -> dict[str, str] | None:
    """The onboard (API) instance the bridge is on: mode 2 at 4,000,000 B/s."""
    return next(
        (
            fields
            for fields in status.values()
            if fields.get("mode") == "2" and float(fields.get("data_rate", 0)) >= 1e6
        ),
        None,
    )
