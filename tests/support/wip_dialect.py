"""A pymavlink dialect generated from MAVLink's own common.xml (tests/data/mavlink_xml).

pymavlink's bundled dialects leave out the work-in-progress messages (ESC_INFO, ESC_STATUS,
COMPONENT_METADATA) the bridge sends for QGroundControl. Decoding them with a dialect that
pymavlink's generator builds from the official XML checks the bridge's hand-declared layouts
and CRC_EXTRA seeds against an independent implementation, not against themselves.
"""

from __future__ import annotations

import contextlib
import functools
import importlib.util
import io
import tempfile
from pathlib import Path
from types import ModuleType
from typing import Any

from tests.support.paths import TEST_DATA

XML = TEST_DATA / "mavlink_xml" / "common.xml"


@functools.cache
def dialect() -> ModuleType:
    """The generated module (built once per test process, under a second)."""
    from pymavlink.generator import mavgen

    out = Path(tempfile.mkdtemp(prefix="mavservo-wip-dialect-")) / "common_wip.py"
    opts = mavgen.Opts(str(out), wire_protocol="2.0", language="Python3", validate=False)
    with contextlib.redirect_stdout(io.StringIO()):
        assert mavgen.mavgen(opts, [str(XML)])
    spec = importlib.util.spec_from_file_location("common_wip", out)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def decode(frame: bytes) -> list[Any]:
    """Every message in ``frame`` (bytes of one or more MAVLink 2 frames)."""
    parser = dialect().MAVLink(None)
    parser.robust_parsing = True
    return [m for m in parser.parse_buffer(bytes(frame)) or [] if m.get_type() != "BAD_DATA"]
