"""rmw_zenoh's names on the wire: data key expressions, liveliness tokens, QoS strings, attachments.

Built exactly as ``rmw_zenoh_cpp`` (Jazzy/Kilted, ``src/detail/liveliness_utils.cpp``,
``attachment_helpers.cpp``, ``qos.cpp``) builds them, so a ROS 2 node running rmw_zenoh finds
SAGE's topics in its graph (``ros2 topic list``) and exchanges samples with them:

- data: ``<domain>/<topic without leading/trailing slash>/<dds type>/<RIHS01 hash>``,
  e.g. ``0/cmd_vel/geometry_msgs::msg::dds_::Twist_/RIHS01_9c45…``;
- liveliness: ``@ros2_lv/<domain>/<zid>/<node id>/<entity id>/<MP|MS|NN>/<enclave>/<namespace>/
  <node>/<topic>/<type>/<hash>/<qos>``, where every ``/`` inside a name becomes ``%``;
- attachment of every sample: sequence number (int64), source timestamp (int64 ns), source gid
  (16 bytes), in Zenoh's serialization format (little-endian integers; the gid as a sequence,
  prefixed by its length as a LEB128 varint).

Pure functions, no Zenoh import: the bridge node opens the session.
"""

from __future__ import annotations

import hashlib
import struct
from dataclasses import dataclass
from enum import IntEnum

ADMIN_SPACE = "@ros2_lv"
SLASH_REPLACEMENT = "%"
QOS_DELIMITER = ":"
QOS_COMPONENT_DELIMITER = ","
GID_SIZE = 16  # RMW_GID_STORAGE_SIZE (bytes)
ATTACHMENT_FORMAT = "<qqB"  # sequence number, source timestamp (ns), gid length (a 1-byte LEB128)
ATTACHMENT_SIZE = struct.calcsize(ATTACHMENT_FORMAT) + GID_SIZE  # 33 bytes


class Entity(IntEnum):
    """Entity kinds in a liveliness token (the value is only an order)."""

    NODE = 0
    PUBLISHER = 1
    SUBSCRIPTION = 2


ENTITY_STR = {Entity.NODE: "NN", Entity.PUBLISHER: "MP", Entity.SUBSCRIPTION: "MS"}


class Reliability(IntEnum):  # rmw_qos_reliability_policy_e
    RELIABLE = 1
    BEST_EFFORT = 2


class Durability(IntEnum):  # rmw_qos_durability_policy_e
    TRANSIENT_LOCAL = 1
    VOLATILE = 2


KEEP_LAST = 1  # rmw_qos_history_policy_e


@dataclass(frozen=True)
class Qos:
    """The QoS parts SAGE sets; deadline, lifespan and liveliness stay rmw_zenoh's defaults."""

    reliability: Reliability = Reliability.RELIABLE
    durability: Durability = Durability.VOLATILE
    depth: int = 10


# rmw_zenoh's defaults (qos.cpp): a field equal to its default is left empty in the token.
DEFAULT_QOS = Qos(Reliability.RELIABLE, Durability.VOLATILE, depth=42)


def mangle(name: str) -> str:
    """A name inside one key chunk: ``/`` → ``%`` (``/`` → ``%``, ``/cmd_vel`` → ``%cmd_vel``)."""
    return name.replace("/", SLASH_REPLACEMENT)


def strip_slashes(name: str) -> str:
    """One leading and one trailing slash removed, as rmw_zenoh's ``strip_slashes``."""
    start = 1 if name.startswith("/") else 0
    end = len(name) - 1 if name.endswith("/") and len(name) > 1 else len(name)
    return name[start:end]


def topic_keyexpr(domain_id: int, topic: str, dds_type: str, type_hash: str) -> str:
    """Key expression of a topic's samples: ``0/scan/sensor_msgs::msg::dds_::LaserScan_/RIHS01_…``."""
    return f"{domain_id}/{strip_slashes(topic)}/{dds_type}/{type_hash}"


def qos_keyexpr(qos: Qos) -> str:
    """The QoS chunk of a liveliness token (``::,10:,:,:,,`` for reliable, volatile, depth 10)."""
    d = DEFAULT_QOS
    reliability = str(int(qos.reliability)) if qos.reliability != d.reliability else ""
    durability = str(int(qos.durability)) if qos.durability != d.durability else ""
    depth = str(qos.depth) if qos.depth != d.depth else ""
    history = ""  # always KEEP_LAST, the default
    # reliability : durability : history,depth : deadline s,ns : lifespan s,ns : liveliness,s,ns
    return QOS_DELIMITER.join([reliability, durability, f"{history},{depth}", ",", ",", ",,"])


@dataclass(frozen=True)
class NodeInfo:
    """A ROS 2 node as rmw_zenoh names it (the namespace and enclave are ``/`` when unset)."""

    domain_id: int
    zid: str  # the Zenoh session id, as ``str(session.info.zid())``
    node_id: int
    name: str
    namespace: str = "/"
    enclave: str = "/"


def liveliness_token(
    node: NodeInfo,
    entity_id: int,
    kind: Entity,
    topic: str = "",
    dds_type: str = "",
    type_hash: str = "",
    qos: Qos | None = None,
) -> str:
    """The liveliness key expression of a node (``kind=NODE``), publisher or subscription."""
    parts = [
        ADMIN_SPACE, str(node.domain_id), node.zid, str(node.node_id), str(entity_id), ENTITY_STR[kind],
        mangle(node.enclave), mangle(node.namespace), mangle(node.name),
    ]  # fmt: skip
    if kind != Entity.NODE:
        if not topic or not dds_type or not type_hash or qos is None:
            raise ValueError(f"a {ENTITY_STR[kind]} token needs a topic, a type, its hash and a QoS")
        parts += [mangle(topic), mangle(dds_type), mangle(type_hash), qos_keyexpr(qos)]
    return "/".join(parts)


def entity_gid(token: str) -> bytes:
    """A 16-byte gid derived from the entity's liveliness token (stable, unique per entity).

    rmw_zenoh (Kilted and later Jazzy releases) hashes the token with XXH3-128; a BLAKE2b digest
    of the same token is used here: a ROS 2 peer only compares gids, it never recomputes them."""
    return hashlib.blake2b(token.encode(), digest_size=GID_SIZE).digest()


@dataclass(frozen=True)
class Attachment:
    """What rmw_zenoh attaches to every sample."""

    sequence_number: int
    source_timestamp_ns: int
    source_gid: bytes

    def encode(self) -> bytes:
        if len(self.source_gid) != GID_SIZE:
            raise ValueError(f"source gid must be {GID_SIZE} bytes, got {len(self.source_gid)}")
        head = struct.pack(ATTACHMENT_FORMAT, self.sequence_number, self.source_timestamp_ns, GID_SIZE)
        return head + self.source_gid

    @classmethod
    def decode(cls, data: bytes) -> Attachment:
        """From a sample's attachment; ``ValueError`` (one line) if it is not rmw_zenoh's."""
        if len(data) != ATTACHMENT_SIZE:
            raise ValueError(f"rmw_zenoh attachment: expected {ATTACHMENT_SIZE} bytes, got {len(data)}")
        seq, stamp, n = struct.unpack_from(ATTACHMENT_FORMAT, data)
        if n != GID_SIZE:
            raise ValueError(f"rmw_zenoh attachment: gid length {n}, expected {GID_SIZE}")
        return cls(seq, stamp, bytes(data[-GID_SIZE:]))
