"""What the bus nodes keep across restarts (DroneCAN: the allocation table), in a file next to
the config: ``<config>.nodes.json``, ``{bus: {profile: {node option: value}}}``.

Read at start and merged into each bus's ``node:`` options (the config's own entries win); a
file that does not parse or does not validate is reported and ignored (the bridge starts with
the config's options: a hostile or corrupted file must not keep it from starting). Written
atomically (:func:`mavservo.config.overlay.write_atomic`) whenever a node's state changes.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from mavservo.config import BusConfig, SmallFileError, read_small_file, write_atomic
from mavservo.scheduling import Scheduler
from mavservo.servos import ProfileOptions, get_profile, node_family

log = logging.getLogger(__name__)
_MAX_BYTES = 1 << 20


def state_path(config_path: str | Path) -> Path:
    """``dronecan.yaml`` -> ``dronecan.yaml.nodes.json``, in the config's directory."""
    path = Path(config_path)
    return path.with_name(path.name + ".nodes.json")


def load(path: Path) -> dict[str, Any]:
    """The saved states, or {} (missing file; one that is unreadable is reported)."""
    if not path.exists():
        return {}
    try:
        data = json.loads(read_small_file(path, _MAX_BYTES))
    except (OSError, SmallFileError, ValueError, RecursionError) as exc:
        # RecursionError: JSON nested thousands deep (a hostile file) exhausts the decoder
        log.warning("node state %s ignored: %s", path, exc)
        return {}
    if not isinstance(data, dict):
        log.warning("node state %s ignored: not a mapping", path)
        return {}
    return data


def bus_node_options(
    bus: BusConfig, saved: Mapping[str, Any], path: Path
) -> dict[str, ProfileOptions]:
    """``bus``'s validated node options, with the saved state merged in, per profile, where the
    merge validates (the file is input like any other: checked by the same ``NodeOptions``)."""
    options = bus.node_options()
    saved_bus = saved.get(bus.name)
    if not isinstance(saved_bus, dict):
        return options
    for name, state in saved_bus.items():
        family = node_family(get_profile(name)) if name in bus.node else None
        if family is None or not isinstance(state, dict):
            continue
        merged = dict(bus.node[name])
        for key, value in state.items():
            if isinstance(value, dict) and isinstance(merged.get(key), dict):
                merged[key] = {**value, **merged[key]}
            else:
                merged.setdefault(key, value)
        try:
            options[name] = family.NodeOptions.model_validate(merged)
        except ValidationError as exc:
            log.warning("node state %s for bus %s ignored: %s", path, bus.name, exc)
    return options


class NodeStateKeeper:
    """Saves the nodes' states when they change (called from the bridge's tick)."""

    def __init__(self, path: Path, saved: Mapping[str, Any]) -> None:
        self.path = path
        self.document: dict[str, Any] = {k: v for k, v in saved.items() if isinstance(v, dict)}
        self._versions: dict[tuple[str, str], int] = {}
        self.writes = 0

    def update(self, schedulers: Iterable[Scheduler]) -> bool:
        """Write the file if any node's state changed; True if it did."""
        changed = False
        for scheduler in schedulers:
            for profile, (version, values) in scheduler.node_states():
                key = (scheduler.name, profile)
                if self._versions.get(key, 0) >= version:
                    continue
                self._versions[key] = version
                self.document.setdefault(scheduler.name, {})[profile] = values
                changed = True
        if changed:
            try:
                write_atomic(self.path, json.dumps(self.document, indent=2, sort_keys=True) + "\n")
                self.writes += 1
            except OSError as exc:
                log.warning("node state %s not saved: %s", self.path, exc)
        return changed
