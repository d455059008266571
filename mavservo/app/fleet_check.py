"""``mavservo check [--one-vehicle] a.yaml b.yaml``: what two bridges on one vehicle would fight
over (named as warnings; with ``--one-vehicle`` as errors).

Several bridges share one vehicle behind a MAVLink router (README, "More than one bridge on a
vehicle"); each must have its own identity. Checked for every pair of files given together:

* a MAVLink component id both would use (servo component or gimbal, on the same system: a
  ``follow`` system id is the autopilot's, so it equals any other);
* the NAMED_VALUE_FLOAT prefix (a dashboard could not tell ``s1_pos`` of one from the other's);
* a servo output channel or actuator index mapped on both (one DO_SET_SERVO would move both
  bridges' servos, and both would ACK a broadcast);
* fixed ESC numbers that overlap (``auto`` moves at run time; two fixed ranges cannot);
* the same local MAVLink listening endpoint, or the same CAN adapter (one process gets it).

Each clash is one line naming both files and what they share; pure (configs in, lines out).
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import combinations

from mavservo.config import ActuatorChannel, Config, ServoOutputChannel


def _system(config: Config) -> str:
    system = config.mavlink.system_id
    return "follow" if system == "follow" else str(system)


def _same_system(a: Config, b: Config) -> bool:
    sa, sb = _system(a), _system(b)
    return "follow" in (sa, sb) or sa == sb


def _components(config: Config) -> dict[int, str]:
    out = {config.mavlink.servo_component_id: "servo component"}
    out.update({g.component_id: f"gimbal {g.name}" for g in config.gimbals})
    return out


def _outputs(config: Config) -> set[str]:
    out = set()
    for channel in config.channels:
        if isinstance(channel, ServoOutputChannel):
            out.add(f"servo output channel {channel.channel}")
        elif isinstance(channel, ActuatorChannel):
            out.add(f"actuator index {channel.index}")
    return out


def _fixed_esc(config: Config) -> set[int]:
    first = config.mavlink.telemetry.esc_first_index
    if first == "auto":
        return set()
    return set(range(int(first), int(first) + len(config.servos)))


def _listen_endpoint(config: Config) -> str | None:
    url = config.mavlink.url
    if url.startswith(("udpin:", "tcpin:", "udp:")) or url.startswith("/dev/"):
        return url.split(",", 1)[0]
    return None


def _adapters(config: Config) -> set[str]:
    return {
        f"{bus.interface}:{bus.channel}"
        for bus in config.can.buses
        if str(bus.channel) != "sim" and bus.interface != "virtual"
    }


def clashes(configs: Sequence[tuple[str, Config]]) -> list[str]:
    """One line per clash between any two of ``configs`` ((path, config) pairs)."""
    lines: list[str] = []
    for (pa, a), (pb, b) in combinations(configs, 2):
        both = f"{pa} and {pb}"
        if _same_system(a, b):
            ca, cb = _components(a), _components(b)
            for cid in sorted(set(ca) & set(cb)):
                lines.append(
                    f"{both}: both use MAVLink component {cid} ({ca[cid]} / {cb[cid]}): "
                    "give one mavlink.servo_component_id 141..153 or gimbals[].component_id "
                    "171..175"
                )
        prefix_a, prefix_b = a.mavlink.telemetry.name_prefix, b.mavlink.telemetry.name_prefix
        if prefix_a == prefix_b:
            lines.append(
                f"{both}: both name their values '{prefix_a}1_pos'...: set "
                "mavlink.telemetry.name_prefix on one (e.g. 't')"
            )
        for output in sorted(_outputs(a) & _outputs(b)):
            lines.append(
                f"{both}: {output} is mapped on both: one command would move servos on both "
                "bridges; map it on one"
            )
        esc = _fixed_esc(a) & _fixed_esc(b)
        if esc:
            lines.append(
                f"{both}: both publish ESC {min(esc)}-{max(esc)}: set one's "
                "mavlink.telemetry.esc_first_index above the other's (or 'auto')"
            )
        endpoint = _listen_endpoint(a)
        if endpoint is not None and endpoint == _listen_endpoint(b):
            lines.append(f"{both}: both listen on {endpoint}: only one can open it")
        for adapter in sorted(_adapters(a) & _adapters(b)):
            lines.append(f"{both}: both open the CAN adapter {adapter}: only one can hold it")
    return lines
