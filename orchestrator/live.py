"""Live view: every logged channel served over the Foxglove WebSocket protocol while a run goes.

:class:`LiveServer` is fed by the MCAP writer itself (``observers.McapObserver``: each schema,
channel and message it writes is handed to the server too), so a live client receives the
same schemas and the same message bytes as the log. The server is ``foxglove-sdk``'s (its
own threads; each client has a bounded queue whose oldest messages are dropped when the
client is slow), so slow or absent clients never slow the simulation or change the log.

A client may also publish (Foxglove's client-publish capability: the Joystick or Teleop
panel, or any client) to the topics a scenario maps onto unit inputs with ``[[live_inputs]]``
(:class:`LiveInput`). The value a person sent is latched at the start of each macro step,
used for that whole step, and recorded with the step's time, so the run can be replayed from
its log exactly (``immersim run SCENARIO --replay RUN.mcap``).
"""
from __future__ import annotations

import json
import logging
import math
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

log = logging.getLogger(__name__)

DEFAULT_HOST = "127.0.0.1"


def parse_address(text: Optional[str]) -> Tuple[str, int]:
    """``HOST:PORT``, ``:PORT``, ``HOST`` or None (localhost, a free port) -> (host, port)."""
    if not text:
        return DEFAULT_HOST, 0
    host, sep, port = text.rpartition(":")
    if not sep:
        return text, 0
    try:
        p = int(port)
    except ValueError:
        raise ValueError(f"--live {text!r}: the port {port!r} is not a number") from None
    if not 0 <= p <= 65535:
        raise ValueError(f"--live {text!r}: the port {p} is not in 0..65535")
    return host or DEFAULT_HOST, p


@dataclass(frozen=True)
class LiveInput:
    """One unit input driven by a live client.

    ``target`` (``unit.variable``) gets ``scale * x + offset`` where ``x`` is the field
    ``field`` (dotted path into the JSON message, list items by index: ``axes.1``,
    ``linear.x``) of the last message a client published on ``topic``; ``initial`` until the
    first message arrives.
    """

    topic: str
    field: str
    target: str
    scale: float = 1.0
    offset: float = 0.0
    initial: float = 0.0

    def extract(self, message: Any) -> Optional[float]:
        value = message
        for part in self.field.split(".") if self.field else ():
            if isinstance(value, list):
                try:
                    value = value[int(part)]
                except (ValueError, IndexError):
                    return None
            elif isinstance(value, dict) and part in value:
                value = value[part]
            else:
                return None
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            return None
        return self.scale * float(value) + self.offset


class LiveInputs:
    """The latest value of each live input, set by the server's thread and latched by the master.

    ``latched`` records every change as ``(t_ns, target, value)``: the time is the start of the
    first macro step that used the value.
    """

    def __init__(self, specs: Sequence[LiveInput]) -> None:
        self.specs = list(specs)
        self._lock = threading.Lock()
        self._latest: Dict[str, float] = {s.target: float(s.initial) for s in self.specs}
        self._used: Dict[str, float] = {}
        self.latched: List[Tuple[int, str, float]] = []
        self.received = 0

    def by_topic(self, topic: str) -> List[LiveInput]:
        return [s for s in self.specs if s.topic == topic]

    def offer(self, topic: str, message: Any) -> None:
        """A client's message on ``topic`` (decoded JSON): updates the inputs mapped from it."""
        with self._lock:
            for spec in self.by_topic(topic):
                v = spec.extract(message)
                if v is not None:
                    self._latest[spec.target] = v
                    self.received += 1

    def signal(self, target: str, source: Optional[Callable[[float], float]] = None):
        """The signal function of ``target`` for the master: called at each step's start with
        the step's time in seconds, returns the value latched for that step (the last one a
        client sent, or ``source(t)`` for a replay) and records it when it changed."""
        def value(t: float) -> float:
            if source is not None:
                v = source(t)
            else:
                with self._lock:
                    v = self._latest[target]
            if self._used.get(target) != v or target not in self._used:
                self._used[target] = v
                self.latched.append((round(t * 1e9), target, v))
            return v
        return value

    def record(self) -> Dict[str, str]:
        """The latched values as MCAP metadata (``live_inputs``): a JSON list of
        ``[t_ns, target, value]`` with each value as its ``float.hex`` (exact)."""
        return {"values": json.dumps([[t, target, float(v).hex()] for t, target, v in self.latched])}


def replay_signals(record: Dict[str, str]) -> Dict[str, List[Tuple[int, float]]]:
    """``live_inputs`` metadata of a log -> per target the ``(t_ns, value)`` changes in order."""
    out: Dict[str, List[Tuple[int, float]]] = {}
    for t, target, v in json.loads(record.get("values", "[]")):
        out.setdefault(target, []).append((int(t), float.fromhex(v)))
    return out


def held(changes: List[Tuple[int, float]], initial: float):
    """Signal function replaying ``changes``: the last value whose time is <= the step's."""
    from bisect import bisect_right

    times = [t for t, _ in changes]
    values = [v for _, v in changes]

    def value(t: float) -> float:
        j = bisect_right(times, round(t * 1e9)) - 1
        return values[j] if j >= 0 else initial
    return value


def attach_live_inputs(scenario: Any, live: Optional["LiveServer"], replay: Any = None) -> Tuple[Any, Optional[LiveInputs]]:
    """The scenario with its ``[[live_inputs]]`` turned into input signals.

    With ``replay`` (an MCAP log of an earlier run) each input replays the values recorded
    there, step by step; otherwise it follows what live clients publish (``initial`` without
    a live view). Returns a copy of the scenario (the given one is left as it is) and the
    :class:`LiveInputs` whose record goes into the log, or None.
    """
    from dataclasses import replace

    from .errors import ScenarioError
    from .scenario import InputSpec

    specs = list(getattr(scenario, "live_inputs", []) or [])
    if not specs:
        if replay is not None:
            raise ScenarioError(f"{scenario.file}: --replay needs [[live_inputs]] to replay, the scenario has none")
        return scenario, None
    inputs = LiveInputs(specs)
    recorded = None
    if replay is not None:
        from .mcapio import read_info

        run = read_info(replay).metadata.get("run", {})
        if "live_inputs" not in run:
            raise ScenarioError(f"{replay}: the log holds no recorded live inputs to replay")
        recorded = replay_signals({"values": run["live_inputs"]})
    extra = []
    for spec in specs:
        unit, var = spec.target.split(".", 1)
        fn = inputs.signal(spec.target, None if recorded is None else held(recorded.get(spec.target, []), spec.initial))
        extra.append(InputSpec(unit, var, "live", {"signal": fn}))
    if live is not None:
        live.listen(inputs)
    return replace(scenario, inputs=list(scenario.inputs) + extra), inputs


class _Listener:
    """foxglove-sdk server listener: client channels and their messages (server thread)."""

    def __init__(self, inputs: Optional[LiveInputs]) -> None:
        self.inputs = inputs
        self.topics: Dict[Tuple[int, int], str] = {}
        self.subscribed = 0
        #: ids of the server's channels subscribed to since the master last looked (list.append
        #: is atomic: the master takes them in :meth:`LiveServer.step`)
        self.joined: List[int] = []

    def on_subscribe(self, client, channel) -> None:
        self.subscribed += 1
        self.joined.append(channel.id)

    def on_unsubscribe(self, client, channel) -> None:
        self.subscribed -= 1

    def on_client_advertise(self, client, channel) -> None:
        self.topics[(client.id, channel.id)] = channel.topic

    def on_client_unadvertise(self, client, client_channel_id: int) -> None:
        self.topics.pop((client.id, client_channel_id), None)

    def on_message_data(self, client, client_channel_id: int, data: bytes) -> None:
        topic = self.topics.get((client.id, client_channel_id))
        if topic is None or self.inputs is None:
            return
        try:
            message = json.loads(data)
        except ValueError:
            log.warning("live input on %s: not a JSON message, ignored", topic)
            return
        self.inputs.offer(topic, message)


class LiveServer:
    """A Foxglove WebSocket server mirroring the MCAP writer's schemas, channels and messages.

    Parameters
    ----------
    host, port : str, int
        Where to listen (port 0: a free port, see :attr:`port`).
    max_rate : float or None
        At most this many messages per channel and wall second are streamed (a channel's first
        message always is): a run going 100x real time makes 3000 steps a wall second, far more
        than a viewer draws, and streaming them all costs the run CPU on the cores it shares with
        the server. None or 0: every message (a run paced at real time makes 30 a second).

    Clients may publish (client-publish capability); what they send reaches unit inputs only
    through the :class:`LiveInputs` given to :meth:`listen`. A channel written once (the
    meshes, :meth:`latch`) is sent again, its last message with its log time, when a client
    subscribes to it after that message: a viewer that joins mid-run still gets the meshes.
    """

    def __init__(self, host: str = DEFAULT_HOST, port: int = 0, max_rate: Optional[float] = 60.0) -> None:
        import foxglove
        from foxglove.websocket import Capability

        self.context = foxglove.Context()
        self.listener = _Listener(None)
        caps = [Capability.ClientPublish]
        try:
            self.server = foxglove.start_server(name="immersim", host=host, port=port, context=self.context,
                                                capabilities=caps, server_listener=self.listener,
                                                supported_encodings=["json"])
        except Exception as exc:   # the SDK reports a bind failure as its own error type
            raise OSError(f"cannot serve the live view on {host}:{port}: {exc}") from None
        self.host, self.port = host, self.server.port
        self._schemas: Dict[int, Any] = {}
        self._channels: Dict[int, Any] = {}
        self._period = 1.0 / max_rate if max_rate else 0.0
        self._last: Dict[int, float] = {}   # channel id -> wall time of its last streamed message
        self._latched: Dict[int, Optional[Tuple[int, bytes]]] = {}   # channel id -> its last message
        self._ids: Dict[int, int] = {}   # the server's channel id -> the log's
        self.messages = 0   # streamed
        self.skipped = 0    # not streamed (max_rate)
        self.resent = 0     # latched messages sent again to a client that subscribed late

    def listen(self, inputs: LiveInputs) -> None:
        """Route what clients publish to ``inputs``."""
        self.listener.inputs = inputs

    # -- fed by the MCAP writer ----------------------------------------------------------
    def schema(self, schema_id: int, name: str, encoding: str, data: bytes) -> None:
        import foxglove

        self._schemas[schema_id] = foxglove.Schema(name=name, encoding=encoding, data=data)

    def channel(self, channel_id: int, topic: str, message_encoding: str, schema_id: int,
                metadata: Optional[Dict[str, str]] = None) -> None:
        import foxglove

        ch = self._channels[channel_id] = foxglove.Channel(
            topic, schema=self._schemas.get(schema_id), message_encoding=message_encoding,
            context=self.context, metadata=dict(metadata or {}))
        self._ids[ch.id()] = channel_id

    def latch(self, channel_id: int) -> None:
        """A client subscribing to ``channel_id`` after its last message gets that message."""
        self._latched[channel_id] = None

    def step(self, log_time: int, items: Sequence[Tuple[int, bytes]]) -> None:
        """The messages of one step, ``(channel id, data)`` at ``log_time`` ns."""
        channels, last, period, latched = self._channels, self._last, self._period, self._latched
        if self.listener.joined:
            self._resend()
        now = time.perf_counter() if period else 0.0
        for cid, data in items:
            ch = channels.get(cid)
            if ch is None:
                continue
            if cid in latched:
                latched[cid] = (log_time, bytes(data))
            if period:
                if now - last.get(cid, -math.inf) < period:
                    self.skipped += 1
                    continue
                last[cid] = now
            ch.log(bytes(data), log_time=log_time)
            self.messages += 1

    def _resend(self) -> None:
        """The latched messages of the channels clients subscribed to since the last step."""
        joined = self.listener.joined
        while joined:
            cid = self._ids.get(joined.pop())
            message = self._latched.get(cid)
            if message is not None:
                self._channels[cid].log(message[1], log_time=message[0])
                self.resent += 1

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def stop(self) -> None:
        self.server.stop()
