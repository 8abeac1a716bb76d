"""The apps' trace records reach trace.jsonl as they come; garbage on the trace keys is counted, never kept."""
from __future__ import annotations

import json
import time
import uuid
from types import SimpleNamespace

from bridges.transport import open_bus
from bridges.v2x import trace_key
from master.run.run_records import TraceRecorder


def test_trace_records_are_kept_and_garbage_is_counted(tmp_path):
    prefix = f"test/trace-{uuid.uuid4().hex[:8]}"
    master = open_bus("memory", prefix=prefix, sender="master")
    app = open_bus("memory", prefix=prefix, sender="rsu")
    recorder = TraceRecorder()
    recorder.open(SimpleNamespace(run_dir=tmp_path, bus=master))
    try:
        app.publish(trace_key("rsu"), json.dumps({"kind": "detections", "frame_id": 3}).encode(), 0.3)
        app.publish(trace_key("rsu"), b"\xff not json", 0.4)
        app.publish(trace_key("rsu"), b"[1, 2]", 0.5)  # JSON, but not a record
        app.publish(trace_key("rsu"), json.dumps({"stamps": {"frame": 1}}).encode(), 0.6)
        deadline = time.monotonic() + 5
        while recorder.records + recorder.garbage < 4 and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        section = recorder.close()
        app.close()
        master.close()
    assert section == {"file": "trace.jsonl", "records": 2, "garbage": 2}
    lines = [json.loads(line) for line in (tmp_path / "trace.jsonl").read_text().splitlines()]
    assert lines == [{"kind": "detections", "frame_id": 3, "app": "rsu"}, {"stamps": {"frame": 1}, "app": "rsu"}]
