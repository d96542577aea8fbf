"""The live view: a plain WebSocket client of the Foxglove protocol gets the log's own
schemas and message bytes, and a client publishing to a [[live_inputs]] topic drives a unit
input, recorded so that a replay gives the same run bit for bit."""
from __future__ import annotations

import json
import math
import re
import struct
import threading
import time

import pytest
from mcap.reader import make_reader
from websockets.sync.client import connect

from immersim.orchestrator.execution import Execution
from immersim.orchestrator.live import LiveInput, LiveInputs, LiveServer, held, parse_address, replay_signals
from immersim.orchestrator.mcapio import read_info

from .helpers import oscillator_scenario

SUBPROTOCOL = "foxglove.sdk.v1"   # foxglove-sdk's server protocol (the SDK is pinned in pyproject)


class Client(threading.Thread):
    """Subscribes to every advertised channel; optionally publishes JSON on one topic."""

    def __init__(self, url: str, publish=None) -> None:
        super().__init__(daemon=True)
        self.url, self.publish = url, publish
        self.channels, self.messages = {}, []
        self.ready = threading.Event()
        self.stop = threading.Event()

    def run(self) -> None:
        with connect(self.url, subprotocols=[SUBPROTOCOL], open_timeout=10) as ws:
            if self.publish:
                topic, _ = self.publish
                ws.send(json.dumps({"op": "advertise", "channels": [
                    {"id": 1, "topic": topic, "encoding": "json", "schemaName": "geometry_msgs/Twist"}]}))
            sub = 0
            while not self.stop.is_set():
                try:
                    msg = ws.recv(timeout=0.05)
                except TimeoutError:
                    continue
                if isinstance(msg, str):
                    m = json.loads(msg)
                    unknown = re.match(r"Unknown channel ID: (\d+)", m.get("message", "")) if m["op"] == "status" else None
                    if unknown:   # advertised before the server could take a subscription: ask again
                        time.sleep(0.02)
                        chid = int(unknown.group(1))
                        sid = next(s for s, ch in self.channels.items() if ch["id"] == chid)
                        ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": sid, "channelId": chid}]}))
                    if m["op"] == "advertise":
                        subs = []
                        for ch in m["channels"]:
                            sub += 1
                            self.channels[sub] = ch
                            subs.append({"id": sub, "channelId": ch["id"]})
                        ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                        self.ready.set()
                    continue
                sid, t_ns = struct.unpack_from("<IQ", msg, 1)
                self.messages.append((self.channels[sid]["topic"], t_ns, bytes(msg[13:])))
                if self.publish and len(self.messages) == 40:   # mid-run: a person pushes the stick
                    ws.send(b"\x01" + struct.pack("<I", 1) + json.dumps(self.publish[1]).encode())


def _log(path):
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        schemas = {c.topic: (summary.schemas[c.schema_id].name, summary.schemas[c.schema_id].encoding,
                             summary.schemas[c.schema_id].data.decode()) for c in summary.channels.values()}
        return schemas, [(c.topic, m.log_time, m.data) for _, c, m in reader.iter_messages()]


def _run_live(scen, out, publish=None, realtime=None):
    """Run with a live view and one client; the client has subscribed before step 1."""
    server = LiveServer(port=0, max_rate=None)   # every message, to compare them all
    client = Client(server.url, publish)
    client.start()
    ex = Execution(scen, out, live=server, realtime=realtime)

    def wait_for_client(k, t_ns):   # an observer: hold the run at step 0 until the client listens
        if k == 0:
            deadline = time.monotonic() + 10
            while server.listener.subscribed < len(server._channels) and time.monotonic() < deadline:
                time.sleep(0.01)
            assert server.listener.subscribed == len(server._channels)
    ex.observers.append(wait_for_client)
    try:
        res = ex.run()
        time.sleep(0.5)   # the server's queue drains to the client
    finally:
        client.stop.set()
        client.join(5)
        server.stop()
    return res, client, ex


def test_live_clients_get_the_logs_schemas_and_bytes(tmp_path, test_fmus):
    scen = oscillator_scenario(tmp_path, test_fmus["oscillator"], step=0.01, stop=1.0)
    out = tmp_path / "live.mcap"
    res, client, _ = _run_live(scen, out)
    schemas, logged = _log(out)
    advertised = {ch["topic"]: (ch["schemaName"], ch["schemaEncoding"], ch["schema"]) for ch in client.channels.values()}
    assert advertised == schemas   # same schemas, byte for byte
    after_start = [m for m in logged if m[1] > 0]   # from step 1 on the client was listening
    got = [m for m in client.messages if m[1] > 0]
    assert len(after_start) == 2 * res.steps_done == 200
    assert sorted(got) == sorted(after_start)   # channels may interleave differently, not their messages
    # decoded with the advertised schema's encoding (JSON), the values are the log's
    assert json.loads(got[-1][2])["x"] == json.loads(after_start[-1][2])["x"]


LIVE = '''
[[live_inputs]]
topic = "/cmd_vel"
field = "linear.x"
target = "m1.x_other"
scale = 2.0
initial = 0.0
'''


def _without(scen_text: str) -> str:
    return scen_text.replace('[[connections]]\nfrom = "m2.x"\nto = "m1.x_other"\n', "")


def test_a_person_at_the_wheel_is_logged_and_replayed_bit_for_bit(tmp_path, test_fmus):
    scen = oscillator_scenario(tmp_path, test_fmus["oscillator"], step=0.01, stop=1.5, extra=LIVE)
    scen.write_text(_without(scen.read_text()))   # m1.x_other is driven by the person, not by m2
    out = tmp_path / "teleop.mcap"
    res, client, ex = _run_live(scen, out, publish=("/cmd_vel", {"linear": {"x": 0.4, "y": 0.0}}), realtime=3.0)
    assert ex.live_inputs.received == 1
    (t_change, target, value), = [c for c in ex.live_inputs.latched if c[2] != 0.0]
    assert (target, value) == ("m1.x_other", 0.8)
    _, logged = _log(out)
    m1 = [(t, json.loads(d)) for topic, t, d in logged if topic == "m1"]
    # the unit saw 0 before the change and 0.8 from the step that latched it on
    assert all(v["x_other"] == (0.8 if t > t_change else 0.0) for t, v in m1 if t > 0)
    assert 0 < t_change < 1.5e9
    # the replay from the log's record: the same run, every message bit for bit
    replayed = tmp_path / "replay.mcap"
    Execution(scen, replayed, replay=out).run()
    assert [m for m in _log(replayed)[1]] == logged
    assert read_info(replayed).metadata["run"]["live_inputs"] == read_info(out).metadata["run"]["live_inputs"]


def test_live_input_fields_and_the_record_round_trip():
    li = LiveInputs([LiveInput("/joy", "axes.1", "u.a", scale=-2.0, offset=1.0),
                     LiveInput("/joy", "buttons.0", "u.b")])
    sig = li.signal("u.a")
    assert sig(0.0) == 0.0
    li.offer("/joy", {"axes": [0.3, 0.25], "buttons": [1]})
    li.offer("/joy", {"axes": [0.3, float("nan")]})   # not finite: ignored
    li.offer("/other", {"axes": [0, 9]})              # another topic: ignored
    assert sig(0.033) == -2.0 * 0.25 + 1.0 and sig(0.066) == 0.5
    record = replay_signals(li.record())
    assert record == {"u.a": [(0, 0.0), (33_000_000, 0.5)]}
    fn = held(record["u.a"], 0.0)
    assert [fn(t) for t in (0.0, 0.032, 0.033, 5.0)] == [0.0, 0.0, 0.5, 0.5]


@pytest.mark.parametrize("text, expected", [(None, ("127.0.0.1", 0)), ("0.0.0.0:8765", ("0.0.0.0", 8765)),
                                            (":9000", ("127.0.0.1", 9000)), ("localhost", ("localhost", 0))])
def test_live_addresses(text, expected):
    assert parse_address(text) == expected


@pytest.mark.parametrize("text, message", [("host:http", "the port 'http' is not a number"),
                                           ("host:70000", "the port 70000 is not in 0..65535")])
def test_bad_live_addresses(text, message):
    with pytest.raises(ValueError, match=message):
        parse_address(text)


def test_teleop_scenario_a_person_drives_the_avatar_and_the_platform_feels_it(tmp_path):
    """scenarios/teleop.toml: a Twist with linear.x = 1 sent mid-run; the avatar stands before the
    step that latched it and drives off after it, the platform's cue follows, the replay is equal."""
    from pathlib import Path

    src = Path(__file__).resolve().parents[2] / "scenarios" / "teleop.toml"
    scen = tmp_path / "teleop.toml"
    scen.write_text(src.read_text().replace("stop = 60.0", "stop = 1.5"))
    out = tmp_path / "teleop.mcap"
    _, _, ex = _run_live(scen, out, publish=("/cmd_vel", {"linear": {"x": 1.0}, "angular": {"z": 0.0}}), realtime=3.0)
    (t_on, _, v), = [c for c in ex.live_inputs.latched if c[1] == "net.avatar[1].throttle" and c[2] != 0.0]
    assert v == 1.0
    _, logged = _log(out)
    net = [(t, json.loads(d)) for topic, t, d in logged if topic == "net"]
    plat = [(t, json.loads(d)) for topic, t, d in logged if topic == "plat"]
    speed = {t: math.hypot(m["avatar[1].vx"], m["avatar[1].vy"]) for t, m in net}
    assert all(s == 0.0 for t, s in speed.items() if t <= t_on)
    assert speed[max(speed)] > 0.5   # full throttle for the rest of the run
    assert max(abs(m["cue.f_x"]) for t, m in plat if t > t_on) > 0.5   # the surge reaches the seat
    replayed = tmp_path / "replay.mcap"
    Execution(scen, replayed, replay=out).run()
    assert _log(replayed)[1] == logged


def test_a_fast_run_streams_at_most_max_rate_messages_per_channel_and_second():
    server = LiveServer(port=0, max_rate=50.0)
    try:
        server.schema(1, "a", "jsonschema", b"{}")
        server.channel(1, "a", "json", 1)
        server.channel(2, "b", "json", 1)
        t0 = time.perf_counter()
        for k in range(3000):
            server.step(k, [(1, b"{}"), (2, b"{}")])
        elapsed = time.perf_counter() - t0
        per_channel = server.messages / 2
        assert server.messages + server.skipped == 6000
        assert 1 <= per_channel <= 1 + 50.0 * elapsed + 1   # the first, then one per 20 ms at most
        server.step(3000, [(3, b"{}")])   # a channel it does not know: nothing
        assert server.messages + server.skipped == 6000
    finally:
        server.stop()


def test_a_viewer_joining_after_the_meshes_still_gets_them():
    """A latched channel (the meshes, written once at the start) is sent again, the log's bytes at
    the log's time, to a client that subscribes after it was written; other channels are not."""
    server = LiveServer(port=0, max_rate=None)
    client = Client(server.url)
    try:
        server.schema(1, "s", "jsonschema", b"{}")
        server.channel(1, "/scene/meshes", "json", 1)
        server.channel(2, "/tf", "json", 1)
        server.latch(1)
        server.step(5, [(1, b'{"meshes":1}'), (2, b'{"tf":5}')])   # before anyone listens
        client.start()
        assert client.ready.wait(10)
        k, deadline = 6, time.monotonic() + 10
        while time.monotonic() < deadline and not any(t == "/scene/meshes" for t, _, _ in client.messages):
            server.step(k, [(2, b'{"tf":%d}' % k)])   # the subscription is handed over with a step
            k += 1
            time.sleep(0.01)
        meshes = {m for m in client.messages if m[0] == "/scene/meshes"}
        assert meshes == {("/scene/meshes", 5, b'{"meshes":1}')} and server.resent >= 1
        assert all(t > 5 for topic, t, _ in client.messages if topic == "/tf")   # not latched: never sent again
    finally:
        client.stop.set()
        server.stop()
