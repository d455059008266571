"""mavservo configuration: the YAML schema and loading with ``FILE:LINE`` errors.

Public API::

    load_config(path) -> Config              # raises ConfigError
    load_config_with_warnings(path) -> (Config, [Problem])  # + settings that will not do as said
    load_config_text(text, filename) -> Config
    default_config_path() -> Path            # the built-in sim.yaml
    bus_loads(config) -> list[BusLoad]       # worst-case R per bus
    endpoint_lines(config) -> list[str]      # MAVLink URL and bus interfaces, in words
    apply_overrides(config, mavlink, port)   # --mavlink / --port; OverrideError names the option

`mavservo check` (which also needs the channel mapping, a layer above) is :mod:`mavservo.app.check`.
"""

from mavservo.config.budget import BusLoad, bus_loads
from mavservo.config.endpoints import endpoint_lines
from mavservo.config.loader import (
    ConfigError,
    default_config_path,
    load_config,
    load_config_text,
    load_config_with_warnings,
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
from mavservo.config.yamlsource import Problem

__all__ = [
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
]
