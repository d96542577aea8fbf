"""Observers only read values. The MCAP observer logs every selected signal.

Layout of the file (see ``immersim info``):

* one channel per unit instance, topic ``<instance>``, JSON messages with a JSON schema
  (each property carries the FMU's unit and description), one message per macro step with
  ``log_time`` = ``publish_time`` = simulation time in nanoseconds;
* one channel ``<instance>/parameters`` with a single message at the start time;
* metadata ``scenario`` (file name and text), ``fmus`` (sha256 per instance), ``immersim``
  (package version, algorithm, step) and, when the run ends, ``run`` (status, completed
  steps, last time, reason).

Messages are JSON objects with the variable names as keys, encoded by orjson (the same text
as ``json.dumps`` for these values), or, with ``[log] encoding = "ros1"``,
packed ROS 1 messages (:func:`ros1_struct`, :func:`ros1_definition`; the JSON schema rides
along as channel metadata). The logging cost of a step is one encoding per channel and one
write of the step's records into the current chunk (:meth:`McapObserver.write_step`).
"""
from __future__ import annotations

import base64
import binascii
import json
import logging
import math
import re
import struct
import time
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

import orjson

from .errors import LogWriteError
from .fmu import VarInfo

log = logging.getLogger(__name__)

_dumps = orjson.dumps
_JSON_TYPE = {"float": "number", "int": "integer", "bool": "boolean", "string": "string"}


def _json_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else "null"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, bytes):   # an FMI 3.0 Binary: base64 text (the schema says contentEncoding)
        return json.dumps(base64.b64encode(value).decode("ascii"))
    return json.dumps(value)


def _base64(value: Any) -> str:
    """The base64 text of an FMI 3.0 Binary value (as :func:`_json_value`); ``TypeError`` for a
    value that is not bytes-like."""
    return binascii.b2a_base64(value, newline=False).decode("ascii")


def json_schema(unit: str, infos: Sequence[VarInfo]) -> Dict[str, Any]:
    props = {}
    for v in infos:
        p: Dict[str, Any] = {"type": _JSON_TYPE.get(v.family, "string")}
        if v.description:
            p["description"] = v.description
        if v.unit:
            p["unit"] = v.unit
        p["causality"] = v.causality
        if v.type in _ROS1_FMI3:   # an FMI 3.0 type with no FMI 2.0 twin: its exact width
            p["fmiType"] = v.type
        if v.family == "binary":
            p["contentEncoding"] = "base64"
        props[v.name] = p
    return {"type": "object", "title": unit, "properties": props}


class ChannelEncoder:
    """Formats one unit's values into a JSON object.

    orjson does it (shortest round-trip floats as ``repr``, ``true``/``false``, non-finite
    Reals as ``null``) in a fraction of the time of ``json.dumps`` or a ``%r`` template; a
    value orjson refuses (bytes, an integer beyond 64 bits) falls back to a template
    formatted value by value.
    """

    def __init__(self, infos: Sequence[VarInfo]) -> None:
        self.infos = list(infos)
        self.names = [v.name for v in self.infos]
        self._template = "{" + ",".join(f"{json.dumps(n)}:%s" for n in self.names) + "}"
        #: the FMI 3.0 Binary variables: their bytes go to orjson as base64 text (converted
        #: before the call: an orjson ``default`` callback per value costs more)
        self._binary = [v.name for v in self.infos if v.family == "binary"]

    def encode(self, values: Sequence[Any]) -> bytes:
        """JSON bytes of one message; ``values`` in the order of ``infos``."""
        try:
            obj = dict(zip(self.names, values))
            for name in self._binary:
                obj[name] = _base64(obj[name])
            return _dumps(obj)
        except TypeError:  # orjson.JSONEncodeError subclasses TypeError
            return (self._template % tuple(_json_value(v) for v in values)).encode()


class Ros1Encoder:
    """Packs one unit's values into a ROS 1 message (:func:`ros1_struct`)."""

    def __init__(self, packer: Any) -> None:
        self._pack = packer.pack

    def encode(self, values: Sequence[Any]) -> bytes:
        """The packed message; ``values`` in the order of the channel's variables."""
        return self._pack(*values)


#: ROS 1 field type and ``struct`` code of each JSON schema type ("ros1" encoding); a
#: variable of another type (a String) has no fixed-size field: its channel is written as JSON
_ROS1 = {"number": ("float64", "d"), "integer": ("int32", "i"), "boolean": ("bool", "?")}
#: FMI 3.0 types of other widths (their JSON schema property says ``fmiType``)
_ROS1_FMI3 = {"Float32": ("float32", "f"), "Int8": ("int8", "b"), "UInt8": ("uint8", "B"),
              "Int16": ("int16", "h"), "UInt16": ("uint16", "H"), "UInt32": ("uint32", "I"),
              "Int64": ("int64", "q"), "UInt64": ("uint64", "Q")}


#: an FMI 3.0 Binary (JSON: base64 text): a ROS 1 ``uint8[]``, no ``struct`` code (variable length)
_ROS1_BINARY = ("uint8[]", None)


def _ros1_kind(prop: Dict[str, Any]) -> Optional[Tuple[str, Optional[str]]]:
    if prop.get("contentEncoding") == "base64":
        return _ROS1_BINARY
    return _ROS1_FMI3.get(prop.get("fmiType")) or _ROS1.get(prop["type"])


class Ros1Packer:
    """``pack(*values)`` and ``unpack(data)`` of a ROS 1 message with ``uint8[]`` fields (FMI
    3.0 Binary values, ``bytes``), as ROS 1 serialises them: a little-endian uint32 length,
    then the bytes; the runs of fixed-size fields between them packed by ``struct``.

    Parameters
    ----------
    codes : sequence of str or None
        Per field, its ``struct`` code, or None for a ``uint8[]``.
    """

    _LENGTH = struct.Struct("<I")

    def __init__(self, codes: Sequence[Optional[str]]) -> None:
        #: (struct of a run of fixed-size fields, or None for one uint8[]; first field; end)
        self.runs: List[Tuple[Optional[struct.Struct], int, int]] = []
        start = 0
        for k, code in enumerate(list(codes) + [None]):
            if code is None:
                if k > start:
                    self.runs.append((struct.Struct("<" + "".join(codes[start:k])), start, k))
                if k < len(codes):
                    self.runs.append((None, k, k + 1))
                start = k + 1

    def pack(self, *values: Any) -> bytes:
        parts = []
        for run, a, b in self.runs:
            if run is None:
                parts += (self._LENGTH.pack(len(values[a])), bytes(values[a]))
            else:
                parts.append(run.pack(*values[a:b]))
        return b"".join(parts)

    def unpack(self, data: bytes) -> tuple:
        out: List[Any] = []
        at = 0
        for run, _, _ in self.runs:
            if run is None:
                (n,) = self._LENGTH.unpack_from(data, at)
                out.append(bytes(data[at + 4:at + 4 + n]))
                at += 4 + n
            else:
                out += run.unpack_from(data, at)
                at += run.size
        return tuple(out)


def ros1_struct(schema: Dict[str, Any]) -> Optional[Any]:
    """How a channel's messages are packed in the "ros1" encoding: the variables of its JSON
    schema (:func:`json_schema`) in order, little-endian, as ROS 1 serialises them. A
    ``struct.Struct`` for fixed-size fields only, a :class:`Ros1Packer` when there are FMI 3.0
    Binary variables (``uint8[]``). None when some variable has no ROS 1 field here (a String:
    its channel, as every unit's parameters channel with one, is written as JSON)."""
    codes = []
    for prop in schema["properties"].values():
        kind = _ros1_kind(prop)
        if kind is None:
            return None
        codes.append(kind[1])
    if None in codes:
        return Ros1Packer(codes)
    return struct.Struct("<" + "".join(codes))


def ros1_definition(schema: Dict[str, Any]) -> str:
    """ROS 1 message definition (``ros1msg``) of a channel: one field per variable, named after
    it with every run of characters a ROS field name cannot hold replaced by ``_`` (made unique),
    the variable's own name, unit and description in the field's comment."""
    used, lines = set(), []
    for name, prop in schema["properties"].items():
        fld = re.sub(r"[^A-Za-z0-9_]+", "_", name).strip("_") or "v"
        if not fld[0].isalpha():
            fld = "v_" + fld
        base, k = fld, 2
        while fld in used:
            fld, k = f"{base}_{k}", k + 1
        used.add(fld)
        note = name + (f" [{prop['unit']}]" if prop.get("unit") else "")
        if prop.get("description"):
            note += ": " + " ".join(str(prop["description"]).split())
        lines.append(f"{_ros1_kind(prop)[0]} {fld}  # {note}")
    return "\n".join(lines) + "\n"


def _fast_writer_class():
    """An ``mcap.writer.Writer`` whose ``add_step`` (and ``add_message``, a one-message step)
    writes a step's records straight into the chunk, one ``struct`` call per record header,
    keeping the chunk index and statistics exactly as the library does
    (``tests/orchestrator/test_mcap_writer.py`` checks the bytes are identical). It uses the
    private state of the mcap version pinned in pyproject.toml, and falls back to the library's
    method when that state is not there."""
    import struct

    from mcap.records import MessageIndex
    from mcap.writer import Writer

    header = struct.Struct("<BQHIQQ")  # opcode, record length, channel, sequence, log, publish time

    class FastMessageIndex(MessageIndex):
        """A chunk's message index kept as a flat list of ints (``flat``: log time, offset,
        log time, offset, ...; ints are not tracked by the garbage collector, tuples are)
        and written with one ``struct.pack`` (the library packs each timestamp and offset
        separately: half a microsecond per message). ``records`` stays empty."""

        def __init__(self, channel_id: int) -> None:
            super().__init__(channel_id=channel_id, records=[])
            self.flat: List[int] = []

        def write(self, stream) -> None:
            n = len(self.flat)  # 2 per message
            stream.write(struct.pack(f"<BQHI{n}Q", 0x07, 6 + 8 * n, self.channel_id, 8 * n, *self.flat))

    class FastWriter(Writer):
        #: a supervisor.Journal: each step's records are copied there until their chunk is on disk
        journal = None
        #: ns added to every message's log and publish time (McapObserver's ``time_offset_ns``)
        time_offset = 0

        def _Writer__finalize_chunk(self) -> None:   # the library's, then the journal is emptied
            Writer._Writer__finalize_chunk(self)
            if self.journal is not None:
                self.journal.committed()

        #: a :class:`~immersim.orchestrator.live.LiveServer` handed every schema, channel and
        #: message written, so a live client gets the log's own bytes (None: no live view)
        tee = None

        def register_schema(self, name: str, encoding: str, data: bytes) -> int:
            sid = super().register_schema(name, encoding, data)
            if self.tee is not None:
                self.tee.schema(sid, name, encoding, data)
            return sid

        def register_channel(self, topic: str, message_encoding: str, schema_id: int,
                             metadata: Optional[Dict[str, str]] = None) -> int:
            cid = super().register_channel(topic, message_encoding, schema_id, metadata or {})
            if self.tee is not None:
                self.tee.channel(cid, topic, message_encoding, schema_id, metadata)
            return cid

        def add_message(self, channel_id: int, log_time: int, data: bytes, publish_time: int,
                        sequence: int = 0) -> None:
            if publish_time != log_time:  # not ours: the library's method
                if self.tee is not None:
                    self.tee.step(log_time, ((channel_id, data),))
                return super().add_message(channel_id, log_time, data, publish_time, sequence)
            self.add_step(log_time, sequence, ((channel_id, data),))  # a one-message step

        def add_step(self, log_time: int, sequence: int, items: Sequence[Tuple[int, bytes]]) -> None:
            """The messages of one macro step (``(channel id, data)`` pairs, all at ``log_time``),
            written straight into the chunk buffer; the chunk is finished, when full, after the
            whole step, so a step is never split across chunks. With one channel the bytes equal
            the library's."""
            if self.tee is not None:
                self.tee.step(log_time, items)
            log_time += self.time_offset   # MCAP times are unsigned: a run from t < 0 is shifted
            try:
                stats = self._Writer__statistics
                cb = self._Writer__chunk_builder
                buf = cb.record_writer._buffer
            except AttributeError:
                for cid, data in items:
                    super().add_message(cid, log_time, data, log_time, sequence)
                return
            if not items:
                return
            if stats.message_count == 0 or log_time < stats.message_start_time:
                stats.message_start_time = log_time
            if log_time > stats.message_end_time:
                stats.message_end_time = log_time
            if cb.num_messages == 0 or log_time < cb.message_start_time:
                cb.message_start_time = log_time
            if log_time > cb.message_end_time:
                cb.message_end_time = log_time
            stats.message_count += len(items)
            cb.num_messages += len(items)
            counts, indices = stats.channel_message_counts, cb.message_indices
            pos = start = buf.tell()
            write = buf.write
            for cid, data in items:
                counts[cid] += 1
                index = indices.get(cid)
                if not index:
                    index = indices[cid] = FastMessageIndex(cid)
                index.flat += (log_time, pos)
                n = len(data)
                pos += 31 + n  # 9 bytes record header + 22 bytes message fields + data
                write(header.pack(0x05, 22 + n, cid, sequence, log_time, log_time))
                write(data)
            if self.journal is not None:
                with buf.getbuffer() as view:
                    self.journal.append(view[start:pos])
            if pos > self._Writer__chunk_size:
                self._Writer__finalize_chunk()

    return FastWriter


class McapObserver:
    """Writes the MCAP log; :meth:`close` always leaves a readable file.

    Chunks are finished after the first step and then at least every ``flush_seconds`` of
    wall time (and at ``CHUNK_BYTES`` of uncompressed data), so a run killed or stopped by a
    full disk keeps the steps of its finished chunks (``immersim info`` reads such a file).

    Parameters
    ----------
    path : Path
        Output file.
    flush_seconds : float
        Wall-clock interval at which the current chunk is flushed to disk, so even a killed
        process keeps almost every completed step.
    tee : LiveServer, optional
        Also handed every schema, channel and message written (the live view).
    time_offset_ns : int
        Added to every message's time (ns): MCAP times are unsigned, a run that starts before
        t = 0 is logged shifted by ``-start`` (metadata ``immersim`` says ``log_time_offset_ns``;
        :mod:`.mcapio` reads the times back unshifted).
    """

    CHUNK_BYTES = 256 * 1024
    #: LZ4: about a quarter of zstd's CPU time per chunk for files about twice as large
    #: (results/orchestrator/README.md compares); both are standard MCAP
    COMPRESSION = "lz4"

    def __init__(self, path: Path | str, flush_seconds: float = 1.0, encoding: str = "json",
                 tee: Any = None, time_offset_ns: int = 0) -> None:
        if encoding not in ("json", "ros1"):
            raise ValueError(f"log encoding {encoding!r} is not json or ros1")
        self.encoding = encoding
        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._fh = open(self.path, "wb")
            from mcap.writer import CompressionType

            self.writer = _fast_writer_class()(self._fh, chunk_size=self.CHUNK_BYTES,
                                               compression=CompressionType[self.COMPRESSION.upper()])
            self.writer.tee = tee
            self.writer.start(profile="", library="immersim")
            self.writer.time_offset = time_offset_ns
            from . import supervisor

            if supervisor.supervised():   # a crash of the process keeps the chunk in progress too
                self.writer.journal = supervisor.Journal(self._fh)
        except OSError as exc:
            raise LogWriteError(f"cannot write the log {self.path}: {exc.strerror or exc}") from None
        self.channels: Dict[str, int] = {}
        self.encoders: Dict[str, Callable[[Sequence[Any]], bytes]] = {}   # topic -> its message encoder
        self.flush_seconds = flush_seconds
        self._last_flush = -float("inf")  # the first step is flushed at once
        self._closed = False
        self.messages = 0

    def add_metadata(self, name: str, data: Dict[str, str]) -> None:
        """One metadata record (written to the file at once); raises LogWriteError."""
        try:
            self.writer.add_metadata(name, {k: str(v) for k, v in data.items()})
        except OSError as exc:
            raise LogWriteError(f"cannot write the log {self.path}: {exc.strerror or exc}") from None

    def add_channel(self, topic: str, infos: Sequence[VarInfo]) -> Tuple[int, Any]:
        """Register a channel with its JSON schema.

        Returns
        -------
        (channel id, encoder)
            The channel id :meth:`write_step` takes and the :class:`ChannelEncoder` or
            :class:`Ros1Encoder` of its values (``encoder.encode(values)``).
        """
        schema = json_schema(topic, infos)
        text = json.dumps(schema)
        packer = ros1_struct(schema) if self.encoding == "ros1" else None
        if packer is None:
            sid = self.writer.register_schema(name=topic, encoding="jsonschema", data=text.encode())
            cid = self.writer.register_channel(topic=topic, message_encoding="json", schema_id=sid)
            encoder: Any = ChannelEncoder(infos)
        else:  # the JSON schema rides along as channel metadata: names, units, descriptions
            sid = self.writer.register_schema(name="immersim/" + re.sub(r"[^A-Za-z0-9_]+", "_", topic),
                                              encoding="ros1msg", data=ros1_definition(schema).encode())
            cid = self.writer.register_channel(topic=topic, message_encoding="ros1", schema_id=sid,
                                               metadata={"jsonschema": text})
            encoder = Ros1Encoder(packer)
        self.channels[topic] = cid
        self.encoders[topic] = encoder.encode
        return cid, encoder

    def write(self, topic: str, t_ns: int, values: Sequence[Any], sequence: int = 0) -> None:
        """One message (non-finite Reals are written as ``null``)."""
        data = self.encoders[topic](values)
        try:
            self.writer.add_message(self.channels[topic], log_time=t_ns, data=data, publish_time=t_ns,
                                    sequence=sequence)
        except OSError as exc:
            raise self._error(exc, t_ns) from None
        self.messages += 1

    def write_step(self, t_ns: int, sequence: int, items: Sequence[Tuple[int, bytes]]) -> None:
        """Log one macro step: one message per channel, then flush to disk now and then.

        Parameters
        ----------
        t_ns : int
            Simulation time of the step's end, ns (log and publish time).
        sequence : int
            Step number.
        items : sequence of (channel id, data)
            Each channel's message, encoded by the encoder :meth:`add_channel` returned.
        """
        try:
            self.writer.add_step(t_ns, sequence, items)
            self.messages += len(items)
            now = time.monotonic()
            if now - self._last_flush > self.flush_seconds:
                self.writer.flush()
                self._last_flush = now
        except OSError as exc:
            raise self._error(exc, t_ns) from None

    def _error(self, exc: OSError, t_ns: int) -> LogWriteError:
        return LogWriteError(f"cannot write the log {self.path} at t = {t_ns / 1e9:.9g} s: {exc.strerror or exc}")

    def close(self) -> None:
        """Finish the file (summary, index). Raises LogWriteError when the disk refuses."""
        if self._closed:
            return
        self._closed = True
        try:
            self.writer.finish()
        except OSError as exc:
            raise LogWriteError(f"cannot finish the log {self.path}: {exc.strerror or exc}") from None
        finally:
            try:
                self._fh.close()
            except OSError:
                pass


#: JSON text of the non-finite floats (JSON has no number for them)
_NON_FINITE = {"nan": "NaN", "inf": "Infinity", "-inf": "-Infinity"}


def write_parameters(obs: McapObserver, unit: str, infos: List[VarInfo], values: List[Any], t_ns: int) -> None:
    """The ``<unit>/parameters`` message. A Real parameter whose value is NaN or infinite (an
    FMU's own start value: the scenario's are checked) is logged as the string ``"NaN"``,
    ``"Infinity"`` or ``"-Infinity"``, its schema type ``string``: never as JSON ``null``."""
    from dataclasses import replace

    topic = f"{unit}/parameters"
    odd = [i for i, v in enumerate(values) if isinstance(v, float) and not math.isfinite(v)]
    if odd:
        infos, values = list(infos), list(values)
        for i in odd:
            infos[i] = replace(infos[i], type="String")
            values[i] = _NON_FINITE[repr(values[i])]
    obs.add_channel(topic, infos)
    obs.write(topic, t_ns, values)
