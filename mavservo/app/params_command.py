"""``mavservo params``: the bridge's MAVLink parameters of a config, its overlay, its metadata.

* ``mavservo params CONFIG``: every parameter with its value, unit and range, marking those that
  come from the overlay (what a ground station set, ``<config stem>.params.yaml``);
* ``mavservo params --clear CONFIG``: remove the overlay (back to the file's values);
* ``mavservo params --metadata FILE CONFIG``: write the parameter metadata (names, units, ranges,
  descriptions, enumerations) as JSON in MAVLink's component-information parameter schema
  (https://mavlink.io/en/services/component_information.html), which QGroundControl reads, so a
  ground station can show what each value means.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from mavservo.app.component_metadata import parameter_metadata as metadata
from mavservo.config import (
    ConfigError,
    Parameter,
    clear_overlay,
    current_values,
    default_config_path,
    load_config_with_overlay,
    overlay_path,
    parameter_table,
)

EXIT_OK = 0
EXIT_INVALID = 2


def build_parser(prog: str = "mavservo params") -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog,
        description="List the MAVLink parameters a config gives the bridge (SRVn_TRIM, ...), "
        "show which values a ground station set (the overlay next to the config), clear them, "
        "or write their metadata for a ground station.",
    )
    parser.add_argument(
        "config", nargs="?", help="config file (default: the built-in simulation config)"
    )
    parser.add_argument(
        "--clear",
        action="store_true",
        help="remove the overlay: every parameter back to the config file's value",
    )
    parser.add_argument(
        "--metadata",
        metavar="FILE",
        help="write the parameter metadata as JSON (MAVLink component-information schema)",
    )
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    path = Path(args.config) if args.config else default_config_path()
    if args.clear:
        removed = clear_overlay(path)
        if removed is None:
            print(f"no overlay for {path} ({overlay_path(path)} does not exist)")
        else:
            print(f"removed {removed}: every parameter is back to {path.name}'s value")
        return EXIT_OK
    try:
        loaded = load_config_with_overlay(path)
    except ConfigError as exc:
        print(f"mavservo: invalid configuration\n{exc}", file=sys.stderr)
        return EXIT_INVALID
    table = parameter_table(loaded.config, loaded.base)
    if args.metadata:
        Path(args.metadata).write_text(json.dumps(metadata(table), indent=2) + "\n")
        print(f"wrote the metadata of {len(table)} parameters to {args.metadata}")
        return EXIT_OK
    print("\n".join(parameter_lines(table, loaded.config, loaded.overlay, path)))
    return EXIT_OK


def parameter_lines(
    table: list[Parameter], config: Any, overlay: dict[str, float], path: Path
) -> list[str]:
    """One line per parameter: name, value, unit, range; ``*`` marks an overlay value."""
    values = current_values(config)
    lines = [f"{'name':<16} {'value':>10}  {'unit':<6} {'range':<22} description"]
    for p in table:
        mark = "*" if p.name in overlay else " "
        span = f"{p.minimum:g}..{p.maximum:g}"
        lines.append(
            f"{p.name:<16} {values[p.name]:>10g}{mark} {p.unit:<6} {span:<22} {p.description}"
        )
    if overlay:
        lines.append(
            f"* set from a ground station, kept in {overlay_path(path)} "
            f"(mavservo params --clear {path} removes it)"
        )
    return lines
