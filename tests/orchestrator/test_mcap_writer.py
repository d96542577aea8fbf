"""Our MCAP writer fast path writes byte-for-byte what the mcap library writes."""
import io
import json

from mcap.reader import make_reader
from mcap.writer import Writer

from immersim.orchestrator.observers import _fast_writer_class


def write(writer_cls, n=5000, channels=3):
    buf = io.BytesIO()
    w = writer_cls(buf, chunk_size=4096)
    w.start(profile="", library="immersim")
    sid = w.register_schema(name="s", encoding="jsonschema", data=b'{"type":"object"}')
    ch = [w.register_channel(topic=f"u{i}", message_encoding="json", schema_id=sid) for i in range(channels)]
    for k in range(n):
        for c in ch:
            w.add_message(c, log_time=k * 33_000_000, data=json.dumps({"x": k * 0.1}).encode(),
                          publish_time=k * 33_000_000, sequence=k)
    w.finish()
    return buf.getvalue()


def test_fast_writer_is_byte_identical_and_readable():
    ours, theirs = write(_fast_writer_class()), write(Writer)
    assert ours == theirs
    msgs = list(make_reader(io.BytesIO(ours)).iter_messages())
    assert len(msgs) == 15000
    assert msgs[-1][2].log_time == 4999 * 33_000_000


def write_steps(n=5000, channels=3):
    buf = io.BytesIO()
    w = _fast_writer_class()(buf, chunk_size=4096)
    w.start(profile="", library="immersim")
    sid = w.register_schema(name="s", encoding="jsonschema", data=b'{"type":"object"}')
    ch = [w.register_channel(topic=f"u{i}", message_encoding="json", schema_id=sid) for i in range(channels)]
    for k in range(n):
        w.add_step(k * 33_000_000, k, [(c, json.dumps({"x": k * 0.1}).encode()) for c in ch])
    w.finish()
    return buf.getvalue()


def test_step_writes_equal_message_writes():
    # one channel: the same bytes as the library's add_message
    assert write_steps(channels=1) == write(Writer, channels=1)
    # several channels: chunks end at step boundaries; the same messages, statistics and indexes
    ours, theirs = make_reader(io.BytesIO(write_steps())), make_reader(io.BytesIO(write(Writer)))
    key = lambda m: (m[1].topic, m[2].log_time, m[2].sequence, m[2].data)  # noqa: E731
    assert [key(m) for m in ours.iter_messages()] == [key(m) for m in theirs.iter_messages()]
    s1, s2 = ours.get_summary().statistics, theirs.get_summary().statistics
    assert (s1.message_count, s1.channel_message_counts, s1.message_start_time, s1.message_end_time) == \
        (s2.message_count, s2.channel_message_counts, s2.message_start_time, s2.message_end_time) == \
        (15000, {1: 5000, 2: 5000, 3: 5000}, 0, 4999 * 33_000_000)
    for ci in ours.get_summary().chunk_indexes:  # every chunk holds whole steps
        assert sorted(ci.message_index_offsets) == [1, 2, 3]


def _log(path, encoding, rows):
    """Write ``rows`` (values per step of three sources) through a LogWriter whose channels log
    all of source 0, positions [2, 0] of source 1, all of source 1, and all and 36 reordered
    positions of source 2 (40 values). Returns the messages by topic."""
    from immersim.orchestrator.fmu import VarInfo
    from immersim.orchestrator.logwriter import LogPlan, LogWriter, _Values

    def infos(*spec):
        return [VarInfo(n, i, t, "output", "continuous", "", 0, "") for i, (n, t) in enumerate(spec)]

    a = infos(("x", "Real"), ("n", "Integer"), ("on", "Boolean"))
    b = infos(("we\"ird name", "Real"), ("y", "Real"), ("z", "Real"))
    long = infos(*[(f"v{i}", "Real") for i in range(40)])
    plan = LogPlan(str(path), encoding=encoding,
                   channels=[("a", a, 0, None), ("b_picked", [b[2], b[0]], 1, [2, 0]), ("b", b, 1, None),
                             ("long", long, 2, None), ("long_picked", [long[i] for i in PICKED], 2, PICKED)])
    sources = [_Values(), _Values(), _Values()]
    w = LogWriter(plan, sources=sources)
    for k, (va, vb) in enumerate(rows):
        sources[0].cur, sources[1].cur, sources[2].cur = va, vb, [k + 0.01 * i for i in range(40)]
        w.write(k, k * 33_000_000)
    w.close({"status": "completed"})
    out = {}
    with open(path, "rb") as fh:
        for _, channel, msg in make_reader(fh).iter_messages():
            out.setdefault(channel.topic, []).append(msg.data)
    return out


PICKED = [(7 * i) % 40 for i in range(36)]


def test_log_step_writes_each_channel_s_picked_values(tmp_path):
    """Each channel's message holds its source's values at its positions, in both encodings,
    including non-finite Reals (JSON ``null``) and a value orjson refuses (an integer beyond
    64 bits: that message takes the template fallback)."""
    import math
    import struct

    rows = [([0.1 * k, k, k % 2 == 0], [k * 1.5, float("nan") if k == 3 else -k, 1e300 * k]) for k in range(50)]
    rows[7] = ([0.7, 2 ** 70, True], rows[7][1])
    msgs = _log(tmp_path / "j.mcap", "json", rows)
    for k, (va, vb) in enumerate(rows):
        assert json.loads(msgs["a"][k]) == {"x": va[0], "n": va[1], "on": va[2]}
        assert json.loads(msgs["b_picked"][k]) == {"z": vb[2], 'we"ird name': vb[0]}
        assert json.loads(msgs["b"][k])["y"] == (None if k == 3 else vb[1])
        assert list(json.loads(msgs["long_picked"][k]).values()) == [k + 0.01 * i for i in PICKED]
    assert json.loads(msgs["a"][3]) == {"x": 0.30000000000000004, "n": 3, "on": False}
    rows[7] = ([0.7, 7, True], rows[7][1])   # ROS 1: a 32-bit Integer field
    msgs = _log(tmp_path / "r.mcap", "ros1", rows)
    for k, (va, vb) in enumerate(rows):
        assert struct.unpack("<di?", msgs["a"][k]) == tuple(va)
        assert struct.unpack("<dd", msgs["b_picked"][k]) == (vb[2], vb[0])
        y = struct.unpack("<ddd", msgs["b"][k])[1]
        assert math.isnan(y) if k == 3 else y == vb[1]
        assert struct.unpack("<36d", msgs["long_picked"][k]) == tuple(k + 0.01 * i for i in PICKED)
