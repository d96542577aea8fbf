"""Read immersim MCAP logs back: channels, signals with units, time series."""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Tuple

import numpy as np

from .errors import ImmersimError
from .patterns import matches


class LogReadError(ImmersimError, OSError):
    """An MCAP file is missing or unreadable."""


@dataclass
class Channel:
    topic: str
    schema: Dict
    count: int = 0
    first_ns: int = 0
    last_ns: int = 0

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


def _reader(path: Path):
    from mcap.reader import make_reader

    if not path.exists():
        raise LogReadError(f"log file {path} does not exist")
    fh = open(path, "rb")
    try:
        return fh, make_reader(fh)
    except Exception as exc:
        fh.close()
        raise LogReadError(f"{path}: not a readable MCAP file: {exc}") from None


def read_info(path: Path | str) -> LogInfo:
    """Channels, signals, message counts, time span and metadata of a log."""
    path = Path(path)
    fh, reader = _reader(path)
    info = LogInfo(path)
    try:
        for schema, channel, message in reader.iter_messages():
            ch = info.channels.get(channel.topic)
            if ch is None:
                ch = info.channels[channel.topic] = Channel(channel.topic, json.loads(schema.data),
                                                            first_ns=message.log_time)
            ch.count += 1
            ch.last_ns = message.log_time
        for md in reader.iter_metadata():
            info.metadata[md.name] = dict(md.metadata)
    except Exception as exc:
        raise LogReadError(f"{path}: error while reading: {exc}") from None
    finally:
        fh.close()
    return info


def read_series(path: Path | str, patterns: List[str]) -> Dict[str, Tuple[np.ndarray, np.ndarray, str]]:
    """Time series of every ``unit.variable`` matching a glob pattern (brackets are literal).

    Returns
    -------
    dict of ``unit.variable`` -> (t in s, shape (n,); values, shape (n,); unit string)
    """
    path = Path(path)
    info = read_info(path)
    wanted: Dict[str, List[str]] = {}
    for topic, ch in info.channels.items():
        if topic.endswith("/parameters"):
            continue
        for var in ch.signals:
            full = f"{topic}.{var}"
            if matches(full, patterns):
                wanted.setdefault(topic, []).append(var)
    if not wanted:
        avail = [f"{t}.{v}" for t, c in info.channels.items() if not t.endswith("/parameters") for v in c.signals]
        raise LogReadError(f"{path}: no signal matches {' '.join(patterns)} "
                           f"(signals: {', '.join(avail[:12])}{' ...' if len(avail) > 12 else ''})")
    times: Dict[str, List[int]] = {t: [] for t in wanted}
    vals: Dict[Tuple[str, str], List[float]] = {(t, v): [] for t, vs in wanted.items() for v in vs}
    fh, reader = _reader(path)
    try:
        for _schema, channel, message in reader.iter_messages(topics=list(wanted)):
            obj = json.loads(message.data)
            times[channel.topic].append(message.log_time)
            for v in wanted[channel.topic]:
                x = obj.get(v)
                vals[(channel.topic, v)].append(np.nan if x is None else float(x))
    finally:
        fh.close()
    out = {}
    for (topic, v), series in vals.items():
        out[f"{topic}.{v}"] = (np.asarray(times[topic], dtype=np.int64) * 1e-9, np.asarray(series),
                               info.channels[topic].unit_of(v))
    return out
