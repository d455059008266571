"""The metadata files a ground station reads to show what each of the bridge's parameters means.

MAVLink's component-information service (https://mavlink.io/en/services/component_information.html)
has a component serve a *general* metadata file (schema ``component_metadata/general.schema.json``
of the MAVLink repository) listing its other metadata files, here the *parameter* metadata
(``parameter.schema.json``: names, units, ranges, descriptions, enumerations). Both are built
from the config's parameter table, once at start: the servo component describes every
parameter, each gimbal component its own. The parameter file is xz-compressed, as the page
advises for files a vehicle hosts (a radio link carries a tenth of the bytes); the general file
stays plain JSON, small.
"""

from __future__ import annotations

import json
import lzma
import re
from importlib.metadata import PackageNotFoundError, version
from typing import Any

from mavservo.config import Config, Parameter, parameter_table
from mavservo.mavlink import (
    COMP_METADATA_TYPE_PARAMETER,
    GENERAL_FILE,
    PARAMETER_FILE,
    crc32,
    mftp_uri,
)

#: parameter.schema.json requires ``version`` >= 3 (the format of the file, not of the bridge).
PARAMETER_SCHEMA_VERSION = 3
GENERAL_SCHEMA_VERSION = 1
_VERSION_PATTERN = re.compile(r"^\d+\.\d+\.\d+(\.\d+)?$")


def parameter_metadata(table: list[Parameter]) -> dict[str, Any]:
    """The parameters in MAVLink's component-information parameter schema."""
    parameters = []
    for p in table:
        entry: dict[str, Any] = {
            "name": p.name,
            "type": "Float",
            "shortDesc": p.description[:80],
            "longDesc": p.description,
            "units": p.unit,
            "min": p.minimum,
            "max": p.maximum,
            "group": "Servos"
            if p.name.startswith("SRV")
            else ("Gimbals" if p.name.startswith("GMB") else "Telemetry"),
        }
        if p.values is not None:
            entry["values"] = [
                {"value": value, "description": text} for value, text in p.values.items()
            ]
        parameters.append(entry)
    return {"version": PARAMETER_SCHEMA_VERSION, "parameters": parameters}


def general_metadata(component_id: int, parameter_file: bytes) -> dict[str, Any]:
    """The general metadata of one component: who it is, where its parameter metadata is."""
    general: dict[str, Any] = {
        "version": GENERAL_SCHEMA_VERSION,
        "vendorName": "mavservo",
        "modelName": "CAN servo bridge",
        "metadataTypes": [
            {
                "type": COMP_METADATA_TYPE_PARAMETER,
                "uri": mftp_uri(component_id, PARAMETER_FILE),
                "fileCrc": crc32(parameter_file),
            }
        ],
    }
    try:
        release = version("mavservo")
    except PackageNotFoundError:
        release = ""
    if _VERSION_PATTERN.match(release):
        general["firmwareVersion"] = release
    return general


def metadata_files(config: Config, envelope: Config | None = None) -> dict[int, dict[str, bytes]]:
    """Component id -> served files: the servo component's and each gimbal component's; the
    angle parameters' ranges are ``envelope``'s limits (the config file's), what a PARAM_SET
    may take."""
    table = parameter_table(config, envelope)
    groups = {config.mavlink.servo_component_id: table}
    for gimbal in config.gimbals:
        groups[gimbal.component_id] = [p for p in table if p.component == gimbal.name]
    files: dict[int, dict[str, bytes]] = {}
    for component_id, parameters in groups.items():
        if not parameters:
            continue
        packed = lzma.compress(
            json.dumps(parameter_metadata(parameters), separators=(",", ":")).encode(),
            format=lzma.FORMAT_XZ,
        )
        general = json.dumps(general_metadata(component_id, packed), indent=1).encode()
        files[component_id] = {GENERAL_FILE: general, PARAMETER_FILE: packed}
    return files
