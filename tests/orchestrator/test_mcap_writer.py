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
