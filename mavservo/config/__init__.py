"""mavservo configuration: the YAML schema, loading with ``FILE:LINE`` errors, and ``check``.

Public API::

    load_config(path) -> Config              # raises ConfigError
    load_config_text(text, filename) -> Config
    default_config_path() -> Path            # the built-in sim.yaml
    resolved_mapping(config) -> str          # human-readable table for `mavservo check`
    bus_loads(config) -> list[BusLoad]       # worst-case R per bus
    check_main(paths) -> int                 # `mavservo check CONFIG...`: 0 valid, 2 invalid
"""

from mavservo.config.budget import BusLoad, bus_loads
from mavservo.config.loader import ConfigError, default_config_path, load_config, load_config_text
from mavservo.config.report import check_main, resolved_mapping
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
    "Problem",
    "SchedulerConfig",
    "ServoConfig",
    "ServoOutputChannel",
    "SigningConfig",
    "SimulationConfig",
    "bus_loads",
    "check_main",
    "default_config_path",
    "load_config",
    "load_config_text",
    "resolved_mapping",
]
