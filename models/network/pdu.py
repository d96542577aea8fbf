"""Protocol data units (fig. 2-4) and the RenderPacket / ControllerPacket payloads (§2.3.2.2).

The original PDU header of fig. 2-4 is packed big-endian with :mod:`struct`:

====================  ======  =====================================================
field                 bytes   meaning
====================  ======  =====================================================
PDU ID                4       globally unique PDU number
PDU Type              2       protocol / operation (:class:`PduType`)
Identify              16      128-bit ID of the sending node
Peer Port             2       sender's port
Peer IP               4       sender's IPv4 address
Time Stamp            8       send time (s, float64)
Reserve               4       reserved (we store the number of records aggregated)
payload length        4       bytes of payload that follow (our addition: framing)
====================  ======  =====================================================

``RenderPacket`` (seed lines ~695-705): ``mIdentify`` (string), ``mPosition`` (Vector3),
``mOrientation`` (Quaternion), ``mSpeed`` (Vector3), ``mStates`` (map<string,string>),
``mCommands`` (map<int,string>). ``ControllerPacket`` (lines ~711-720): ``mIdentify``,
``mAcceleration`` (float), ``mTinyOrient`` (float), ``mStates``, ``mCommands``. Strings are a
uint16 length plus UTF-8 bytes; maps a uint16 count plus their entries; floats are float32
(the Ogre Vector3/Quaternion). The entity's acceleration, needed by second-order dead
reckoning, travels in ``mStates['acc']`` as three packed float32, as the thesis puts per-entity
state in ``mStates``.
"""
from __future__ import annotations

import enum
import functools
import ipaddress
import struct
from dataclasses import dataclass, field
from typing import Dict, List, Tuple

HEADER = struct.Struct("!IH16sH4sdII")
_U16 = struct.Struct("!H")
_I32 = struct.Struct("!i")
_VEC = struct.Struct("!3f")
_QUAT = struct.Struct("!4f")
_CTRL = struct.Struct("!2f")


class PduType(enum.IntEnum):
    """PDU types used by the model."""

    HEARTBEAT = 1
    JOIN = 2
    LEAVE = 3
    CONTROL = 10        # ControllerPacket: controller -> supernode -> master
    FRAME = 20          # master -> slave: next frame (RenderPackets of every object in view)
    STATE = 21          # master -> master (same cluster): updates of owned objects
    REPORT = 22         # slave -> master: dynamic entities and collisions in the slave's view
    HANDOVER = 23       # old owner -> new owner of an entity
    RELAY = 30          # client-server: a batch relayed by the server


def _pack_str(s: str) -> bytes:
    raw = s.encode("utf-8")
    return _U16.pack(len(raw)) + raw


def _unpack_str(buf: bytes, off: int) -> Tuple[str, int]:
    (n,) = _U16.unpack_from(buf, off)
    off += 2
    return buf[off:off + n].decode("utf-8"), off + n


def _pack_maps(states: Dict[str, str], commands: Dict[int, str]) -> bytes:
    out = [_U16.pack(len(states))]
    for k, v in states.items():
        out += [_pack_str(k), _pack_str(v)]
    out.append(_U16.pack(len(commands)))
    for k, v in commands.items():
        out += [_I32.pack(k), _pack_str(v)]
    return b"".join(out)


def _unpack_maps(buf: bytes, off: int) -> Tuple[Dict[str, str], Dict[int, str], int]:
    (n,) = _U16.unpack_from(buf, off)
    off += 2
    states = {}
    for _ in range(n):
        k, off = _unpack_str(buf, off)
        v, off = _unpack_str(buf, off)
        states[k] = v
    (n,) = _U16.unpack_from(buf, off)
    off += 2
    commands = {}
    for _ in range(n):
        (k,) = _I32.unpack_from(buf, off)
        v, off = _unpack_str(buf, off + 4)
        commands[k] = v
    return states, commands, off


@dataclass
class RenderPacket:
    """Render-node state packet (seed line ~695). Units: m, m/s; orientation a unit quaternion."""

    identify: str
    position: Tuple[float, float, float] = (0.0, 0.0, 0.0)
    orientation: Tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    speed: Tuple[float, float, float] = (0.0, 0.0, 0.0)
    states: Dict[str, str] = field(default_factory=dict)
    commands: Dict[int, str] = field(default_factory=dict)

    def pack(self) -> bytes:
        return (_pack_str(self.identify) + _VEC.pack(*self.position) + _QUAT.pack(*self.orientation)
                + _VEC.pack(*self.speed) + _pack_maps(self.states, self.commands))

    @classmethod
    def unpack(cls, buf: bytes, off: int = 0) -> Tuple["RenderPacket", int]:
        ident, off = _unpack_str(buf, off)
        pos = _VEC.unpack_from(buf, off)
        quat = _QUAT.unpack_from(buf, off + 12)
        spd = _VEC.unpack_from(buf, off + 28)
        states, commands, off = _unpack_maps(buf, off + 40)
        return cls(ident, pos, quat, spd, states, commands), off


@dataclass
class ControllerPacket:
    """Control-platform packet (seed line ~711): acceleration (m/s^2) and tiny orientation change (rad)."""

    identify: str
    acceleration: float = 0.0
    tiny_orient: float = 0.0
    states: Dict[str, str] = field(default_factory=dict)
    commands: Dict[int, str] = field(default_factory=dict)

    def pack(self) -> bytes:
        return (_pack_str(self.identify) + _CTRL.pack(self.acceleration, self.tiny_orient)
                + _pack_maps(self.states, self.commands))

    @classmethod
    def unpack(cls, buf: bytes, off: int = 0) -> Tuple["ControllerPacket", int]:
        ident, off = _unpack_str(buf, off)
        acc, orient = _CTRL.unpack_from(buf, off)
        states, commands, off = _unpack_maps(buf, off + 8)
        return cls(ident, acc, orient, states, commands), off


@dataclass
class Pdu:
    """Original PDU of fig. 2-4 carrying a list of packets as payload."""

    pdu_id: int
    pdu_type: int
    identify: int
    peer_ip: str
    peer_port: int
    timestamp: float
    packets: List[object] = field(default_factory=list)

    def pack(self) -> bytes:
        payload = b"".join(p.pack() for p in self.packets)
        return HEADER.pack(self.pdu_id, int(self.pdu_type), self.identify.to_bytes(16, "big"), self.peer_port,
                           ipaddress.IPv4Address(self.peer_ip).packed, self.timestamp, len(self.packets),
                           len(payload)) + payload

    @classmethod
    def unpack(cls, buf: bytes) -> "Pdu":
        pid, ptype, ident, port, ip, ts, count, plen = HEADER.unpack_from(buf, 0)
        body = buf[HEADER.size:HEADER.size + plen]
        if len(body) != plen:
            raise ValueError(f"PDU {pid}: payload length {plen} but {len(body)} bytes follow")
        kind = ControllerPacket if ptype == PduType.CONTROL else RenderPacket
        packets, off = [], 0
        for _ in range(count):
            pkt, off = kind.unpack(body, off)
            packets.append(pkt)
        return cls(pid, PduType(ptype), int.from_bytes(ident, "big"), str(ipaddress.IPv4Address(ip)), port, ts, packets)


def object_record(obj: int, order: int) -> RenderPacket:
    """A representative RenderPacket of object ``obj`` as sent with prediction order ``order``."""
    states = {"acc": "x" * _VEC.size} if order >= 2 else {}
    return RenderPacket(f"E{obj:06d}", (1.0, 2.0, 0.0), (1.0, 0.0, 0.0, 0.0), (0.1, 0.2, 0.0), states)


@functools.lru_cache(maxsize=None)  # sizes are constant: pack once, not every frame
def record_bytes(order: int) -> int:
    """Bytes of one object's RenderPacket (measured by packing one), prediction order ``order``."""
    return len(object_record(0, order).pack())


@functools.lru_cache(maxsize=None)  # sizes are constant: pack once, not every frame
def controller_bytes() -> int:
    """Bytes of one ControllerPacket with empty maps."""
    return len(ControllerPacket("C0000").pack())


@functools.lru_cache(maxsize=None)  # sizes are constant: pack once, not every frame
def report_bytes() -> int:
    """Bytes of a slave's report (one RenderPacket with a collision command)."""
    return len(RenderPacket("R0000", commands={1: "collide"}).pack())


def pdu_bytes(n_records: int, record_size: int) -> int:
    """Bytes of a PDU aggregating ``n_records`` records of ``record_size`` bytes."""
    return HEADER.size + n_records * record_size
