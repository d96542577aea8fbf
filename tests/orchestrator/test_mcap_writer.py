"""Our MCAP writer fast path writes byte-for-byte what the mcap library writes."""
import io
import json

from mcap.reader import make_reader
from mcap.writer import Writer

from immersim.orchestrator.observers import _fast_writer_class


def write(writer_cls, n=5000):
    buf = io.BytesIO()
    w = writer_cls(buf, chunk_size=4096)
    w.start(profile="", library="immersim")
    sid = w.register_schema(name="s", encoding="jsonschema", data=b'{"type":"object"}')
    ch = [w.register_channel(topic=f"u{i}", message_encoding="json", schema_id=sid) for i in range(3)]
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
