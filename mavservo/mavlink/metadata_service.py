"""Component metadata for ground stations: COMPONENT_METADATA and the files it points at.

QGroundControl asks each component for COMPONENT_METADATA (MAV_CMD_REQUEST_MESSAGE 397), reads
the general metadata file at its ``uri`` over MAVLink FTP, and from it the parameter metadata
file (https://mavlink.io/en/services/component_information.html). The files are built by the
application from the config (this layer knows nothing of the config); here each hosted
component gets its read-only :class:`~mavservo.mavlink.ftp.FtpServer`, and a component without
files still answers FTP at once (NAK "file not found": MAVProxy's parameter download then
falls back to PARAM_REQUEST_LIST instead of waiting for its time-out).

The URI names the component (``mftp://[;comp=140]/general.json``, the MAVLink FTP URL scheme),
so a ground station that reaches the bridge through the autopilot's routing still asks the
right component. Sans-I/O.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.mavlink.answers import Answer
from mavservo.mavlink.commands import Outgoing
from mavservo.mavlink.ftp import MAX_DATA, ByteWindow, FtpServer, Sender, crc32
from mavservo.mavlink.wip_messages import ComponentMetadata

#: The general metadata file's name on every component that serves metadata.
GENERAL_FILE = "general.json"
#: The parameter metadata file (xz-compressed JSON, as the component-information page advises).
PARAMETER_FILE = "parameters.json.xz"
#: COMP_METADATA_TYPE (common.xml): 0 general, 1 parameter.
COMP_METADATA_TYPE_PARAMETER = 1
#: MAV_CMD_REQUEST_MESSAGE's message id for COMPONENT_METADATA.
MSG_COMPONENT_METADATA = ComponentMetadata.id  # = commands.MSG_COMPONENT_METADATA
URI_LENGTH = 100


def mftp_uri(component_id: int, name: str) -> str:
    """A MAVLink FTP URI for ``name`` on ``component_id`` (at most 100 characters)."""
    uri = f"mftp://[;comp={component_id}]/{name}"
    if len(uri) > URI_LENGTH:
        raise ValueError(f"metadata URI {uri!r} is longer than {URI_LENGTH} characters")
    return uri


class MetadataService:
    """COMPONENT_METADATA answers and the FTP servers of the hosted components.

    ``files``: component id -> (served name -> content); a component with a
    :data:`GENERAL_FILE` answers COMPONENT_METADATA. ``bytes_per_s``: the byte rate the FTP
    answers of all components together may take of the link.
    """

    def __init__(
        self,
        component_ids: Iterable[int],
        files: Mapping[int, Mapping[str, bytes]],
        *,
        bytes_per_s: float,
        boot_time: float,
        chunk_bytes: int = MAX_DATA,
    ) -> None:
        self._boot = boot_time
        window = ByteWindow(bytes_per_s)  # one link: every component's answers share it
        self.servers = {
            cid: FtpServer(
                dict(files.get(cid, {})),
                bytes_per_s=bytes_per_s,
                window=window,
                chunk_bytes=chunk_bytes,
            )
            for cid in component_ids
        }
        self._first = 0

    def component_metadata(self, component_id: int, now: float) -> Any | None:
        """COMPONENT_METADATA of ``component_id``, or None when it serves no metadata."""
        server = self.servers.get(component_id)
        if server is None or GENERAL_FILE not in server.files:
            return None
        return ComponentMetadata(
            time_boot_ms=int((now - self._boot) * 1000) & 0xFFFFFFFF,
            file_crc=crc32(server.files[GENERAL_FILE]),
            uri=mftp_uri(component_id, GENERAL_FILE),
        )

    def handle(self, msg: Any, component_id: int, sender: Sender, now: float) -> None:
        """A FILE_TRANSFER_PROTOCOL request addressed to ``component_id``."""
        server = self.servers.get(component_id)
        if server is not None:
            server.handle(bytes(msg.payload), sender, now)

    def due(self, now: float, admit: Callable[[int, Any, bool], bool]) -> list[Answer]:
        """The FTP replies that go now, each to its requester only: each component's server
        in turn (the one served first rotates), each reply admitted by ``admit(component, msg,
        awaited)`` (the link budget's answers:
        :meth:`~mavservo.mavlink.bandwidth.LinkBudget.admit_answer`; ``awaited``: a reply a
        client waits for, not a refusal)."""
        out: list[Answer] = []
        servers = list(self.servers.items())
        if servers:
            self._first = (self._first + 1) % len(servers)
            servers = servers[self._first :] + servers[: self._first]
        for cid, server in servers:

            def admit_payload(payload: bytes, awaited: bool, cid: int = cid) -> bool:
                return admit(cid, _message(payload, (0, 0)), awaited)

            for to, payload in server.due(now, admit_payload):
                out.append(Answer(cid, _message(payload, to), to))
        return out

    def periodic(self, now: float) -> list[Outgoing]:
        """The FTP answers each component may send now, without a link budget."""
        return [(a.component_id, a.msg) for a in self.due(now, lambda _c, _m, _a: True)]

    def stats(self) -> dict[str, dict[str, int]]:
        return {str(cid): server.stats() for cid, server in self.servers.items()}


def _message(payload: bytes, to: tuple[int, int] | Sender) -> Any:
    """FILE_TRANSFER_PROTOCOL carrying ``payload`` to ``to`` (system, component)."""
    return mavlink2.MAVLink_file_transfer_protocol_message(0, to[0], to[1], list(payload))
