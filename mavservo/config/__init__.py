"""mavservo configuration: the YAML schema and loading with ``FILE:LINE`` errors.

Public API::

    load_config(path) -> Config              # raises ConfigError
    load_config_with_warnings(path) -> (Config, [Problem])  # + settings that will not do as said
    load_config_text(text, filename) -> Config
    default_config_path() -> Path            # the built-in sim.yaml
    bus_loads(config) -> list[BusLoad]       # worst-case R per bus
    endpoint_lines(config) -> list[str]      # MAVLink URL and bus interfaces, in words
    apply_overrides(config, mavlink, port)   # --mavlink / --port; OverrideError names the option
    preflight(path, mavlink=, port=)         # the verdict `check` prints and `run` starts from

`mavservo check` (which also needs the channel mapping, a layer above) is :mod:`mavservo.app.check`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from mavservo.config.budget import BusLoad, bus_loads
from mavservo.config.endpoints import endpoint_lines
from mavservo.config.loader import (
    ConfigError,
    default_config_path,
    load_config,
    load_config_text,
    load_config_with_warnings,
    load_located,
)
from mavservo.config.overrides import OverrideError, apply_overrides
from mavservo.config.schema import (
    ActuatorChannel,
    BusConfig,
    ChannelConfig,
    Config,
    FailsafeConfig,
    GimbalConfig,
    LoggingConfig,
    MavlinkConfig,
    SchedulerConfig,
    ServoConfig,
    ServoOutputChannel,
    SigningConfig,
    SimulationConfig,
)
from mavservo.config.yamlsource import Problem, YamlDocument, format_path
from mavservo.faces import lazy_face

__all__ = [
    "SimAutopilotConfig",
    "timing_config",
    "telemetry_rates",
    "servo_specs",
    "mavlink_settings",
    "gimbal_settings",
    "ActuatorChannel",
    "BusConfig",
    "BusLoad",
    "ChannelConfig",
    "Config",
    "ConfigError",
    "FailsafeConfig",
    "GimbalConfig",
    "LoggingConfig",
    "MavlinkConfig",
    "OverrideError",
    "Problem",
    "SchedulerConfig",
    "ServoConfig",
    "ServoOutputChannel",
    "SigningConfig",
    "SimulationConfig",
    "apply_overrides",
    "bus_loads",
    "default_config_path",
    "endpoint_lines",
    "load_config",
    "load_config_text",
    "load_config_with_warnings",
    "load_located",
    "YamlDocument",
    "format_path",
]

# The face: what the other layers use from this package (``tests/test_package_faces.py``), each
# name imported from its module on first use (:func:`mavservo.faces.lazy_face`); the modules'
# other names are the package's own business.
if TYPE_CHECKING:
    from .autopilot_script import (
        Action,
        Dropout,
        Event,
        GimbalTarget,
        RepeatServo,
        Script,
        SetActuator,
        SetServo,
        parse_script,
        repeat_servo_value,
    )
    from .budget import bus_nodes, servos_on
    from .endpoints import bitrate_text, describe_bus
    from .overlay import (
        LoadedConfig,
        clear_overlay,
        load_config_with_overlay,
        overlay_path,
        write_atomic,
        write_overlay,
    )
    from .parameters import (
        Parameter,
        ParameterError,
        current_values,
        float32,
        parameter_table,
        with_values,
    )
    from .schema import SimAutopilotConfig, allowed_values, default_text, read_key_file
    from .simulation import Faults, Physics
    from .smallfile import SmallFileError, read_small_file
    from .start_checks import (
        Preflight,
        SimulatedAutopilotError,
        preflight,
        refuse_simulated_autopilot_on_hardware,
    )
    from .tunnel_plan import tunnel_filter_ids, tunnel_keeps_extended, tunnel_plan_lines
    from .views import (
        gimbal_settings,
        mavlink_settings,
        servo_specs,
        telemetry_rates,
        timing_config,
    )

__all__ += [
    "Action",
    "Dropout",
    "Event",
    "Faults",
    "GimbalTarget",
    "LoadedConfig",
    "Parameter",
    "ParameterError",
    "Physics",
    "Preflight",
    "RepeatServo",
    "Script",
    "SetActuator",
    "SetServo",
    "SimulatedAutopilotError",
    "SmallFileError",
    "allowed_values",
    "default_text",
    "bitrate_text",
    "bus_nodes",
    "clear_overlay",
    "current_values",
    "describe_bus",
    "float32",
    "load_config_with_overlay",
    "overlay_path",
    "parameter_table",
    "parse_script",
    "preflight",
    "read_key_file",
    "refuse_simulated_autopilot_on_hardware",
    "read_small_file",
    "repeat_servo_value",
    "servos_on",
    "tunnel_filter_ids",
    "tunnel_keeps_extended",
    "tunnel_plan_lines",
    "with_values",
    "write_atomic",
    "write_overlay",
]
__getattr__ = lazy_face(
    __name__,
    {
        "SimAutopilotConfig": "schema",
        "timing_config": "views",
        "telemetry_rates": "views",
        "servo_specs": "views",
        "mavlink_settings": "views",
        "gimbal_settings": "views",
        "Action": "autopilot_script",
        "Dropout": "autopilot_script",
        "Event": "autopilot_script",
        "Faults": "simulation",
        "GimbalTarget": "autopilot_script",
        "LoadedConfig": "overlay",
        "Parameter": "parameters",
        "ParameterError": "parameters",
        "Physics": "simulation",
        "Preflight": "start_checks",
        "SimulatedAutopilotError": "start_checks",
        "preflight": "start_checks",
        "refuse_simulated_autopilot_on_hardware": "start_checks",
        "RepeatServo": "autopilot_script",
        "Script": "autopilot_script",
        "SetActuator": "autopilot_script",
        "SetServo": "autopilot_script",
        "SmallFileError": "smallfile",
        "allowed_values": "schema",
        "default_text": "schema",
        "bitrate_text": "endpoints",
        "bus_nodes": "budget",
        "clear_overlay": "overlay",
        "current_values": "parameters",
        "describe_bus": "endpoints",
        "float32": "parameters",
        "load_config_with_overlay": "overlay",
        "overlay_path": "overlay",
        "parameter_table": "parameters",
        "parse_script": "autopilot_script",
        "read_key_file": "schema",
        "read_small_file": "smallfile",
        "repeat_servo_value": "autopilot_script",
        "servos_on": "budget",
        "tunnel_filter_ids": "tunnel_plan",
        "tunnel_keeps_extended": "tunnel_plan",
        "tunnel_plan_lines": "tunnel_plan",
        "with_values": "parameters",
        "write_atomic": "overlay",
        "write_overlay": "overlay",
    },
)
