"""The log repair after a crash (``supervisor.repair_log``) against a file written here with the
``mcap`` library: every channel and its messages are kept, each once, and the run record replaced."""
import json

from mcap.reader import make_reader
from mcap.writer import Writer

from immersim.orchestrator.supervisor import repair_log

TOPICS = ("/a", "/b", "/c")


def _write(fh, steps, chunk_size):
    w = Writer(fh, chunk_size=chunk_size)
    w.start(profile="", library="test")
    sid = w.register_schema("s", "jsonschema", b'{"type": "object"}')
    cids = [w.register_channel(t, "json", sid) for t in TOPICS]
    w.add_metadata("run", {"status": "running"})
    for k in range(1, steps + 1):
        for i, c in enumerate(cids):
            w.add_message(c, k * 1000, json.dumps({"k": k, "i": i}).encode(), k * 1000, k)
    return w


def _read(path):
    with open(path, "rb") as fh:
        r = make_reader(fh)
        got = {}
        for _, ch, m in r.iter_messages():
            got.setdefault(ch.topic, []).append((m.sequence, json.loads(m.data)))
        meta = {m.name: m.metadata for m in r.iter_metadata()}
        topics = sorted(c.topic for c in r.get_summary().channels.values())
    return got, meta, topics


def test_repair_keeps_every_channel_of_a_finished_file(tmp_path):
    """A complete file (each channel record in its chunk and again in the summary): three
    channels of six messages each, the run record replaced by the one given."""
    p = tmp_path / "run.mcap"
    with open(p, "wb") as fh:
        _write(fh, 6, 1024).finish()
    assert repair_log(str(p), b"", {"status": "crashed", "steps_done": 6}) == (6, 0)
    got, meta, topics = _read(p)
    assert topics == sorted(TOPICS)
    for i, t in enumerate(TOPICS):
        assert got[t] == [(k, {"k": k, "i": i}) for k in range(1, 7)]
    assert meta["run"] == {"status": "crashed", "steps_done": "6"}


def test_repair_of_a_cut_file_keeps_its_complete_chunks_of_every_channel(tmp_path):
    """No summary (the process died): the messages of the complete chunks, on all three
    channels, and the steps it could not keep named in the run record."""
    p = tmp_path / "run.mcap"
    with open(p, "wb") as fh:
        _write(fh, 40, 256)   # several small chunks on disk, the last one still open, no summary
    last, lost = repair_log(str(p), b"", {"status": "crashed", "steps_done": 40, "reason": "SIGKILL"})
    got, meta, topics = _read(p)
    assert topics == sorted(TOPICS)
    assert 0 < last < 40 and lost == 40 - last
    for i, t in enumerate(TOPICS):
        assert [s for s, _ in got[t]] == list(range(1, len(got[t]) + 1))
        assert all(d == {"k": s, "i": i} for s, d in got[t])
    assert max(s for t in TOPICS for s, _ in got[t]) == last
    assert meta["run"]["reason"] == f"SIGKILL; steps {last + 1}..40 were lost"
