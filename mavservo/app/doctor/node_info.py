"""DroneCAN ``uavcan.protocol.GetNodeInfo``: the doctor asks each node it heard by NodeStatus
for its name, software and hardware version and unique id, as a tool node.

From the DSDL ``uavcan/protocol/1.GetNodeInfo.uavcan`` (as shipped in the ``dronecan``
package): a "full node info request" with an empty request section, a read that changes nothing
on the node; the response carries ``status`` (NodeStatus), ``software_version`` (major, minor,
``optional_field_flags``: bit 0 ``vcs_commit`` set, bit 1 ``image_crc`` set),
``hardware_version`` (major, minor, ``unique_id[16]``, a certificate) and ``name`` (up to 80
ASCII bytes, a reversed domain name). A service transfer needs a node id of the sender: the
doctor uses 127, an id kept for tools (MAVLink's "UAVCAN interaction" guide: "the values 126
and 127 are typically used by debugging or monitoring equipment"); ``--node-id`` picks another,
and nothing is asked when a node on the bus has it. The request and the
reader of the answers are the DroneCAN family's (:mod:`mavservo.servos.dronecan.get_node_info`).
"""

from __future__ import annotations

#: The node id kept for tools (a GUI tool, a debugger; see the module docstring).
TOOL_NODE_ID = 127
#: How long the answers to the requests of one bus are waited for (a node answers within a few
#: ms; a GetNodeInfo response is ~10 frames).
ANSWER_WAIT_S = 0.3
#: The most nodes asked on one bus (a bus carries at most 127; a flood of spoofed NodeStatus
#: ids cannot make the doctor send more).
MAX_NODES_ASKED = 127
