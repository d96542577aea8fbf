"""Read immersim MCAP logs back: channels, signals with units, time series."""
from __future__ import annotations

import base64
import json
from dataclasses import dataclass, field
from pathlib import Path
import logging
from typing import Callable, Dict, List, Optional, Tuple

import numpy as np

from .errors import ImmersimError
from .patterns import matches

log = logging.getLogger(__name__)


class LogReadError(ImmersimError, OSError):
    """An MCAP file is missing or unreadable."""


@dataclass
class Channel:
    topic: str
    schema: Dict
    count: int = 0
    first_ns: int = 0
    last_ns: int = 0
    encoding: str = "json"

    @property
    def signals(self) -> List[str]:
        return list(self.schema.get("properties", {}))

    def unit_of(self, var: str) -> str:
        return self.schema.get("properties", {}).get(var, {}).get("unit", "")


@dataclass
class LogInfo:
    path: Path
    channels: Dict[str, Channel] = field(default_factory=dict)
    metadata: Dict[str, Dict[str, str]] = field(default_factory=dict)
    #: the file ended early (a killed process or a full disk): only its complete records were read
    truncated: bool = False


def _check_exists(path: Path) -> None:
    """Refuse what cannot be a log: a missing file, a folder, a file this user cannot read."""
    if not path.exists():
        raise LogReadError(f"log file {path} does not exist")
    if path.is_dir():
        raise LogReadError(f"{path} is a folder, not an MCAP log file")
    try:
        with open(path, "rb"):
            pass
    except OSError as exc:
        raise LogReadError(f"cannot read the log {path}: {exc.strerror or exc}") from None


def _salvage(path: Path, topics: Optional[List[str]] = None) -> Tuple[List[Tuple], Dict[str, Dict[str, str]]]:
    """Every complete message and metadata record of a file that ends early.

    A run stopped by a full disk or a killed process leaves no summary; the records written
    up to that point (finished chunks) are read in order until the first incomplete one.
    """
    from mcap.records import Channel as ChannelRecord, Chunk, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader, breakup_chunk

    schemas, channels, out, metadata = {}, {}, [], {}
    with open(path, "rb") as fh:
        try:
            for record in StreamReader(fh, skip_magic=False, emit_chunks=True).records:
                inner = breakup_chunk(record) if isinstance(record, Chunk) else [record]
                for r in inner:
                    if isinstance(r, Schema):
                        schemas[r.id] = r
                    elif isinstance(r, ChannelRecord):
                        channels[r.id] = r
                    elif isinstance(r, Message):
                        ch = channels[r.channel_id]
                        if topics is None or ch.topic in topics:
                            out.append((schemas[ch.schema_id], ch, r))
                    elif isinstance(r, Metadata):
                        metadata[r.name] = dict(r.metadata)
        except Exception as exc:  # the first incomplete record ends what can be read
            log.info("%s: read up to an incomplete record (%s)", path, exc)
    if not out and not metadata:
        raise LogReadError(f"{path}: not a readable MCAP file (no complete record)")
    return out, metadata


def _messages(path: Path, topics: Optional[List[str]] = None):
    """``(messages, metadata, truncated)``; messages as (schema, channel, message) tuples, their
    times the simulation times (a log shifted by ``log_time_offset_ns``, a run from t < 0, is
    shifted back)."""
    from mcap.reader import make_reader

    _check_exists(path)
    try:
        with open(path, "rb") as fh:
            reader = make_reader(fh)
            msgs = list(reader.iter_messages(topics=topics))
            metadata = {md.name: dict(md.metadata) for md in reader.iter_metadata()}
        truncated = False
    except Exception:
        (msgs, metadata), truncated = _salvage(path, topics), True
    offset = int(metadata.get("immersim", {}).get("log_time_offset_ns", 0) or 0)
    if offset:
        from dataclasses import replace

        msgs = [(s, c, replace(m, log_time=m.log_time - offset, publish_time=m.publish_time - offset))
                for s, c, m in msgs]
    return msgs, metadata, truncated


def binary_variables(js: Dict) -> List[str]:
    """The FMI 3.0 Binary variables of a channel's JSON schema (base64 text in JSON, ``uint8[]``
    in ros1; read back as ``bytes`` from either)."""
    return [n for n, p in js.get("properties", {}).items() if p.get("contentEncoding") == "base64"]


def channel_schema(schema, channel) -> Tuple[Dict, Callable[[bytes], Dict]]:
    """The JSON schema of a channel and the decoder of its messages (JSON objects, or the
    "ros1" packing of :func:`~immersim.orchestrator.observers.ros1_struct`), FMI 3.0 Binary
    values as ``bytes`` in both. A ros1 channel without a JSON schema (the 3D view's ``/tf``)
    has no signals."""
    if channel.message_encoding == "ros1":
        if "jsonschema" not in channel.metadata:   # not a unit's channel (e.g. the 3D view's /tf)
            return {"title": schema.name if schema else channel.topic, "properties": {}}, lambda data: {}
        from .observers import ros1_struct

        js = json.loads(channel.metadata["jsonschema"])
        names, unpack = list(js["properties"]), ros1_struct(js).unpack
        return js, lambda data: dict(zip(names, unpack(data)))
    js = json.loads(schema.data)
    binary = binary_variables(js)
    if not binary:
        return js, json.loads

    def decode(data: bytes) -> Dict:
        obj = json.loads(data)
        for n in binary:
            if isinstance(obj.get(n), str):
                obj[n] = base64.b64decode(obj[n])
        return obj
    return js, decode


def read_info(path: Path | str) -> LogInfo:
    """Channels, signals, message counts, time span and metadata of a log (also of a log that
    ends early: then ``truncated`` is set and the complete records are counted)."""
    path = Path(path)
    info = LogInfo(path)
    msgs, info.metadata, info.truncated = _messages(path)
    for schema, channel, message in msgs:
        ch = info.channels.get(channel.topic)
        if ch is None:
            ch = info.channels[channel.topic] = Channel(channel.topic, channel_schema(schema, channel)[0],
                                                        first_ns=message.log_time,
                                                        encoding=channel.message_encoding)
        ch.count += 1
        ch.last_ns = message.log_time
    return info


_SCALAR = ("number", "integer", "boolean")


def read_series(path: Path | str, patterns: List[str]) -> Dict[str, Tuple[np.ndarray, np.ndarray, str]]:
    """Time series of every ``unit.variable`` matching a glob pattern (brackets are literal).

    Returns
    -------
    dict of ``unit.variable`` -> (t in s, shape (n,); values, shape (n,); unit string)
    """
    path = Path(path)
    msgs, _, _ = _messages(path)   # one pass: the channels' schemas from their first messages, then the values
    channels: Dict[str, Tuple[Dict, Callable[[bytes], Dict]]] = {}
    for schema, channel, _ in msgs:
        if channel.topic not in channels:
            channels[channel.topic] = channel_schema(schema, channel)
    wanted: Dict[str, List[str]] = {}
    for topic, (js, _) in channels.items():
        if topic.endswith("/parameters"):
            continue
        for var, prop in js.get("properties", {}).items():
            # signals are numbers (a unit's Real, Integer, Boolean): not the arrays of a 3D view's
            # /tf and /scene, nor a String
            if prop.get("type") in _SCALAR and matches(f"{topic}.{var}", patterns):
                wanted.setdefault(topic, []).append(var)
    if not wanted:
        avail = [f"{t}.{v}" for t, (js, _) in channels.items() if not t.endswith("/parameters")
                 for v in js.get("properties", {})]
        raise LogReadError(f"{path}: no signal matches {' '.join(patterns)} "
                           f"(signals: {', '.join(avail[:12])}{' ...' if len(avail) > 12 else ''})")
    times: Dict[str, List[int]] = {t: [] for t in wanted}
    vals: Dict[Tuple[str, str], List[float]] = {(t, v): [] for t, vs in wanted.items() for v in vs}
    for _, channel, message in msgs:
        names = wanted.get(channel.topic)
        if names is None:
            continue
        obj = channels[channel.topic][1](message.data)
        times[channel.topic].append(message.log_time)
        for v in names:
            x = obj.get(v)
            vals[(channel.topic, v)].append(np.nan if x is None else float(x))
    out = {}
    for (topic, v), series in vals.items():
        out[f"{topic}.{v}"] = (np.asarray(times[topic], dtype=np.int64) * 1e-9, np.asarray(series),
                               channels[topic][0]["properties"][v].get("unit", ""))
    return out
