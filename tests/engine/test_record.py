"""run.json is a versioned model with one writer; every reader goes through it."""

from __future__ import annotations

import json

import pytest

from lanegraph.errors import InputError, NodeError
from lanegraph.run.outcome import FrameFailure, RunResult
from lanegraph.run.record import RECORD_VERSION, RunRecord, read_record, stopped_by, write_run_files
from lanegraph.run.results import find_result


def _result() -> RunResult:
    r = RunResult(frames=3, results={"lanes": "lanes.jsonl"})
    r.failures.append(FrameFailure("0002", 2, "fit", "lanes.fit", "ValueError: no points"))
    return r


def test_a_record_round_trips_through_its_one_writer(tmp_path):
    rec = RunRecord.of(
        _result(), graph="g.yaml", input="in", sequence="seq", command=["lanegraph", "run"], origin="a test",
        frames="0:3",
    )  # fmt: skip
    write_run_files(tmp_path, rec)
    data = json.loads((tmp_path / "run.json").read_text())
    assert data["version"] == RECORD_VERSION and data["status"] == "failed frames" and "stopped" not in data
    assert data["command"] == ["lanegraph", "run"] and data["selection"]["frames"] == "0:3"
    assert data["origin"] == "a test"  # a field this version does not know is kept
    back = read_record(tmp_path)
    assert back == rec and back.failures[0]["node"] == "fit"
    assert json.loads((tmp_path / "timings.json").read_text())["frames"] == 3


def test_a_stopped_run_says_where(tmp_path):
    exc = NodeError("fit", "lanes.fit", "0002", ValueError("boom"))
    rec = RunRecord.of(_result(), graph="g.yaml", stopped=stopped_by(exc), before_any_frame=False)
    write_run_files(tmp_path, rec)
    data = json.loads((tmp_path / "run.json").read_text())
    assert (
        data["status"] == "stopped"
        and data["stopped"]["node"] == "fit"
        and data["stopped"]["frame"] == "0002"
    )
    assert data["error"] == str(exc)


def test_older_and_hand_written_records_read_with_defaults(tmp_path):
    (tmp_path / "run.json").write_text('{"results": {"lanes": "x.jsonl", "bad": 5}, "frames_ok": 2}')
    rec = read_record(tmp_path)
    assert (
        rec.version == 0
        and rec.results == {"lanes": "x.jsonl"}
        and rec.frames_ok == 2
        and rec.timings is None
    )
    (tmp_path / "x.jsonl").write_text("{}\n")
    assert find_result(tmp_path) == tmp_path / "x.jsonl"


def test_a_file_that_is_not_a_record(tmp_path):
    assert read_record(tmp_path) is None
    (tmp_path / "run.json").write_text("[1, 2]")
    assert read_record(tmp_path) is None
    with pytest.raises(InputError, match="expected a JSON object") as info:
        read_record(tmp_path, strict=True)
    assert str(tmp_path / "run.json") in str(info.value)
    (tmp_path / "run.json").write_text('{"frames_ok": "many"}')
    with pytest.raises(InputError, match="frames_ok"):
        read_record(tmp_path, strict=True)
