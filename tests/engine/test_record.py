"""run.json is a versioned model with one writer; every reader goes through it."""

from __future__ import annotations

import json

import pytest
from pydantic import ValidationError

from lanegraph.errors import InputError, NodeError
from lanegraph.records.record import (
    RECORD_VERSION,
    CommandRecord,
    Provenance,
    RunRecord,
    VariantEntry,
    read_record,
    stopped_by,
    write_command_record,
    write_run_files,
)
from lanegraph.records.results import find_result
from lanegraph.run.outcome import FrameFailure, RunResult


def _result() -> RunResult:
    r = RunResult(frames=3, results={"lanes": "lanes.jsonl"})
    r.failures.append(FrameFailure("0002", 2, "fit", "lanes.fit", "ValueError: no points"))
    return r


def test_a_record_round_trips_through_its_one_writer(tmp_path):
    rec = RunRecord.of(
        _result(), graph="g.yaml", input="in", sequence="seq", provenance=Provenance(command=["lanegraph", "run"]),
        frames="0:3",
    )  # fmt: skip
    write_run_files(tmp_path, rec)
    data = json.loads((tmp_path / "run.json").read_text())
    assert data["version"] == RECORD_VERSION and data["status"] == "failed frames" and "stopped" not in data
    assert data["command"] == ["lanegraph", "run"] and data["selection"]["frames"] == "0:3"
    back = read_record(tmp_path)
    assert back == rec and back.failures[0]["node"] == "fit"
    assert json.loads((tmp_path / "timings.json").read_text())["frames"] == 3


def test_a_misspelt_field_is_refused_and_an_unknown_one_read_past(tmp_path):
    """No extras: a field the model does not have cannot be written; one in a file (a newer
    lanegraph's) is left out when it is read."""
    with pytest.raises(TypeError, match="origin"):
        RunRecord.of(_result(), graph="g.yaml", origin="a test")  # type: ignore[call-arg]
    with pytest.raises(ValidationError, match="comand"):
        Provenance(comand=["lanegraph"])  # type: ignore[call-arg]
    assert RunRecord.model_config.get("extra") != "allow"  # what it reads: a newer lanegraph's fields ignored
    (tmp_path / "run.json").write_text('{"frames_ok": 2, "origin": "a newer lanegraph"}')
    rec = read_record(tmp_path)
    assert rec.frames_ok == 2 and "origin" not in rec.model_dump()


def test_command_json_is_a_model_with_one_writer(tmp_path):
    made = Provenance(command=["lanegraph", "ablate"], versions={"lanegraph": "x"})
    rec = CommandRecord.of("ablation", made, {"kind": "ablation"}, ["results.md"],
                           [VariantEntry(name="paper", graph="graphs/paper.yaml")])  # fmt: skip
    write_command_record(tmp_path, rec)
    data = json.loads((tmp_path / "command.json").read_text())
    assert data["kind"] == "ablation" and data["command"] == ["lanegraph", "ablate"]
    assert data["variants"] == [{"name": "paper", "graph": "graphs/paper.yaml", "sets": []}]
    assert CommandRecord.model_validate(data) == rec
    with pytest.raises(ValidationError):
        CommandRecord(kind="sweep")  # not a kind of command record


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
