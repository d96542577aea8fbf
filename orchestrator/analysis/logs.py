"""An immersim MCAP log as arrays per channel or as one pandas DataFrame.

Values come out exactly as logged: a "ros1" channel is read with a numpy structured dtype
over the packed messages (the same bytes, no float conversion; one with FMI 3.0 Binary
``uint8[]`` fields message by message), a JSON channel through ``orjson`` (shortest
round-trip floats, ``null`` for a non-finite Real reads as NaN, Binary base64 text as bytes).
"""
from __future__ import annotations

import base64
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, Iterable, List, Optional, Sequence

import numpy as np

from ..mcapio import LogReadError, _messages, binary_variables, channel_schema
from ..observers import _ros1_kind, ros1_struct
from ..patterns import matches


def _ros1_dtype(prop: Dict) -> str:
    """numpy dtype of a variable in a ros1 message: the little-endian ``struct`` code the log
    writer packs it with (:func:`~immersim.orchestrator.observers.ros1_struct`, FMI 3.0 widths
    included)."""
    return "<" + _ros1_kind(prop)[1]


def _objects(values: List) -> np.ndarray:
    """A 1-D object array of ``values`` (``bytes`` kept whole, not split by numpy)."""
    out = np.empty(len(values), dtype=object)
    out[:] = values
    return out


#: dtype of each JSON schema type read from JSON messages
_JSON_DTYPE = {"number": np.float64, "integer": np.int64, "boolean": np.bool_, "string": object}
SIGNAL_TYPES = tuple(_JSON_DTYPE)


@dataclass
class ChannelData:
    """The signals of one unit's channel.

    Attributes
    ----------
    topic : str
        The unit's instance name.
    t_ns : ndarray of int64, shape (n,)
        Log time of each message (simulation time in ns).
    values : dict of str -> ndarray, shape (n,)
        Per variable: float64 (Real), int32/int64 (Integer; an FMI 3.0 type at its own width),
        bool (Boolean) or object (String: str; FMI 3.0 Binary: bytes, from base64 text in JSON
        and ``uint8[]`` in ros1).
    units, types : dict of str -> str
        Per variable: its unit ("" when none) and JSON schema type (number, integer, boolean, string).
    """

    topic: str
    t_ns: np.ndarray
    values: Dict[str, np.ndarray] = field(default_factory=dict)
    units: Dict[str, str] = field(default_factory=dict)
    types: Dict[str, str] = field(default_factory=dict)

    @property
    def t(self) -> np.ndarray:
        """Time in s, shape (n,)."""
        return self.t_ns / 1e9


def _is_unit_channel(topic: str) -> bool:
    return not topic.startswith("/") and not topic.endswith("/parameters")


def _decode(topic: str, channel, datas: List[bytes], t_ns: np.ndarray, wanted: Sequence[str],
            props: Dict) -> ChannelData:
    """The ``wanted`` variables of one channel's messages ``datas`` (schema properties ``props``)."""
    out = ChannelData(topic, t_ns, units={v: props[v].get("unit", "") for v in wanted},
                      types={v: props[v]["type"] for v in wanted})
    binary = set(binary_variables({"properties": props}))
    if channel.message_encoding == "ros1" and not binary:
        dtype = np.dtype([(f"f{i}", _ros1_dtype(p)) for i, p in enumerate(props.values())])
        rec = np.frombuffer(b"".join(datas), dtype=dtype, count=len(datas))
        index = {name: f"f{i}" for i, name in enumerate(props)}
        for v in wanted:
            out.values[v] = rec[index[v]].copy()
        return out
    if channel.message_encoding == "ros1":   # uint8[] fields: message by message
        unpack, index = ros1_struct({"properties": props}).unpack, {name: i for i, name in enumerate(props)}
        rows = [unpack(d) for d in datas]
        for v in wanted:
            col = [r[index[v]] for r in rows]
            out.values[v] = _objects(col) if v in binary else np.array(col, dtype=_ros1_dtype(props[v]))
        return out
    import orjson

    objs = [orjson.loads(d) for d in datas]
    for v in wanted:
        col = [o.get(v) for o in objs]
        kind = props[v]["type"]
        if v in binary:
            out.values[v] = _objects([base64.b64decode(x) for x in col])
        elif kind == "number":
            out.values[v] = np.array([np.nan if x is None else x for x in col], dtype=np.float64)
        elif kind == "integer" and props[v].get("fmiType"):   # an FMI 3.0 width (UInt64 beyond int64)
            out.values[v] = np.array(col, dtype=_ros1_dtype(props[v]))
        else:
            out.values[v] = np.array(col, dtype=_JSON_DTYPE[kind])
    return out


def read_channels(path: Path | str, patterns: Iterable[str] = ("*",)) -> Dict[str, ChannelData]:
    """The units' channels of a log, with the variables matching ``patterns``.

    Parameters
    ----------
    path : path-like
        An immersim MCAP log (a file that ends early is read up to its last complete record).
    patterns : iterable of str
        Globs over ``unit.variable`` (``*`` and ``?`` wildcards, brackets literal).

    Returns
    -------
    dict of topic -> :class:`ChannelData`, in log order; channels without a match are left out.

    Raises
    ------
    LogReadError
        The file is missing or unreadable, or no signal matches.
    """
    path, patterns = Path(path), list(patterns)
    msgs, _, _ = _messages(path)
    meta: Dict[str, tuple] = {}
    datas: Dict[str, List[bytes]] = {}
    times: Dict[str, List[int]] = {}
    for schema, channel, message in msgs:
        topic = channel.topic
        if topic not in meta:
            if not _is_unit_channel(topic):
                meta[topic] = None
                continue
            props = channel_schema(schema, channel)[0].get("properties", {})
            wanted = [v for v, p in props.items()
                      if p.get("type") in SIGNAL_TYPES and matches(f"{topic}.{v}", patterns)]
            meta[topic] = (channel, props, wanted) if wanted else None
            datas[topic], times[topic] = [], []
        if meta[topic] is None:
            continue
        datas[topic].append(message.data)
        times[topic].append(message.log_time)
    out = {topic: _decode(topic, m[0], datas[topic], np.asarray(times[topic], dtype=np.int64), m[2], m[1])
           for topic, m in meta.items() if m is not None}
    if not out:
        raise LogReadError(f"{path}: no signal matches {' '.join(patterns)}")
    return out


def read_log(path: Path | str, patterns: Iterable[str] = ("*",), frame: bool = True):
    """Read a log's signals: a DataFrame, or the arrays per channel.

    Parameters
    ----------
    path : path-like
        An immersim MCAP log.
    patterns : iterable of str
        Globs over ``unit.variable`` (default: every signal of every unit).
    frame : bool
        True: a :class:`pandas.DataFrame`; False: :func:`read_channels`' dict of
        :class:`ChannelData` (numpy arrays per channel).

    Returns
    -------
    pandas.DataFrame
        Index ``t`` (simulation time in s, float64; channels logged at other times are joined
        on the union, missing samples NaN), one column per ``unit.variable`` holding the logged
        values bit for bit. ``df.attrs``: ``units`` and ``types`` (dicts column -> str),
        ``t_ns`` (the index in integer ns) and ``path``.
    """
    import pandas as pd

    channels = read_channels(path, patterns)
    if not frame:
        return channels
    parts, units, types = [], {}, {}
    for topic, ch in channels.items():
        cols = {f"{topic}.{v}": a for v, a in ch.values.items()}
        parts.append(pd.DataFrame(cols, index=pd.Index(ch.t_ns, name="t_ns")))
        units.update({f"{topic}.{v}": u for v, u in ch.units.items()})
        types.update({f"{topic}.{v}": k for v, k in ch.types.items()})
    same = all(len(p.index) == len(parts[0].index) and np.array_equal(p.index, parts[0].index) for p in parts)
    df = pd.concat(parts, axis=1) if same else pd.concat(parts, axis=1, join="outer", sort=True)
    t_ns = df.index.to_numpy(dtype=np.int64)
    df.index = pd.Index(t_ns / 1e9, name="t")
    df.attrs.update(units=units, types=types, t_ns=t_ns, path=str(path))
    return df


def unit_label(name: str, units: Optional[Dict[str, str]]) -> str:
    """``name [unit]``, or ``name`` when it has no unit."""
    u = (units or {}).get(name, "")
    return f"{name} [{u}]" if u else name
