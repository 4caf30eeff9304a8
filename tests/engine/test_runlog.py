"""Logging: the console's levels (-v / -q) and a run's own log, OUT/run.log, with every warning and
every error a node raised on a frame."""

from __future__ import annotations

import copy
import logging
import os
import stat
import warnings

import pytest

from lanegraph.nodes import RunContext
from lanegraph.run.executor import Executor
from lanegraph.runlog import RunLog, configure_console, console_level, get_logger

from .test_executor import load
from .test_graph import VALID


def test_console_levels():
    assert console_level() == logging.INFO and console_level(quiet=1) == logging.INFO  # -q: no bars
    assert console_level(verbose=1) == logging.DEBUG and console_level(verbose=3) == logging.DEBUG
    assert console_level(quiet=2) == logging.WARNING and console_level(quiet=3) == logging.ERROR


@pytest.mark.parametrize(
    ("verbose", "quiet", "shown"),
    [
        (0, 0, ["a note", "warning: a doubt", "error: a failure"]),
        (1, 0, ["debug: a detail", "a note", "warning: a doubt", "error: a failure"]),
        (0, 1, ["a note", "warning: a doubt", "error: a failure"]),  # -q: no progress bars only
        (0, 2, ["warning: a doubt", "error: a failure"]),
        (0, 3, ["error: a failure"]),
    ],
)
def test_console_prints_each_level_as_a_line(capsys, verbose, quiet, shown):
    undo = configure_console(verbose, quiet)
    try:
        log = get_logger("run")
        log.debug("a detail")
        log.info("a note")
        log.warning("a doubt")
        log.error("a failure")
    finally:
        undo()
    err = capsys.readouterr().err
    assert err.splitlines() == shown


@pytest.mark.parametrize(("quiet", "shown"), [(1, ["a note", "warning: a doubt"]), (2, ["warning: a doubt"])])
def test_a_line_a_command_says_is_a_note_that_q_keeps_and_qq_hides(capsys, quiet, shown):
    """``say``'s docstring said a note was hidden by ``-q``: ``-q`` only turns the progress bars
    off (a long wait still says what it is doing); ``-qq`` hides notes."""
    from lanegraph.runlog import say

    undo = configure_console(0, quiet)
    try:
        say("a note")
        say("warning: a doubt")
    finally:
        undo()
    assert capsys.readouterr().err.splitlines() == shown


def test_python_warnings_reach_the_console_while_configured(capsys):
    undo = configure_console()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always")
            logging.captureWarnings(True)  # catch_warnings restored showwarning: capture again
            warnings.warn("cache full", UserWarning, stacklevel=1)
    finally:
        undo()
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("warning: ") and "UserWarning: cache full" in err[0]
    assert not logging.getLogger("py.warnings").handlers or all(
        type(h).__name__ != "_ConsoleHandler" for h in logging.getLogger("py.warnings").handlers
    )


def test_undo_leaves_no_handler():
    before = list(logging.getLogger("lanegraph").handlers)
    undo = configure_console(1, 0)
    undo2 = configure_console(0, 1)  # replaces the first
    assert sum(type(h).__name__ == "_ConsoleHandler" for h in logging.getLogger("lanegraph").handlers) == 1
    undo2()
    undo()
    assert logging.getLogger("lanegraph").handlers == before


def test_run_log_records_warnings_and_every_node_error_with_its_frame(tmp_path, pm):
    d = copy.deepcopy(VALID)
    d["nodes"]["double"]["on_error"] = "skip"
    g = load(tmp_path, pm, d, sets=["double.fail_on=2"])
    out = tmp_path / "out"
    out.mkdir()
    old = os.umask(0o022)
    try:
        with RunLog(out, pm=pm):
            get_logger("run").info("run of %s", g.name)
            res = Executor(g, RunContext(out_dir=out), pm).run()
            for w in res.warnings():
                get_logger("run").warning(w)
            get_logger("run").debug("not recorded without -v")
    finally:
        os.umask(old)
    text = (out / "run.log").read_text()
    lines = text.splitlines()
    assert any(line.endswith(f"INFO lanegraph.run: run of {g.name}") for line in lines)
    errors = [line for line in lines if "WARNING" in line and "raised" in line]
    assert (
        len(errors) == 1 and "frame 0002: node 'double' (toy.scale) raised ValueError: boom on 2" in errors[0]
    )
    assert "not recorded" not in text
    assert stat.S_IMODE((out / "run.log").stat().st_mode) == 0o644  # the umask's, as any file
    # detached: nothing more goes to the file, the hook is gone
    get_logger("run").warning("after the run")
    Executor(g, RunContext(out_dir=out), pm).run()
    assert (out / "run.log").read_text() == text


def test_run_log_is_written_anew_or_continued_and_never_through_a_link(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_text("keep\n")
    (out / "run.log").symlink_to(victim)
    with RunLog(out):
        get_logger().warning("first")
    assert victim.read_text() == "keep\n" and not (out / "run.log").is_symlink()
    with RunLog(out, append=True, verbose=True):
        get_logger().debug("second")
    lines = (out / "run.log").read_text().splitlines()
    assert [line.split(": ", 1)[1] for line in lines] == ["first", "second"]
    with RunLog(out):
        get_logger().warning("third")
    assert [line.split(": ", 1)[1] for line in (out / "run.log").read_text().splitlines()] == ["third"]


# --------------------------------------------------------------------------- progress when piped
def test_piped_progress_prints_a_start_line_then_at_most_one_line_an_interval(capsys):
    from lanegraph.runlog import PipedProgress

    now = [100.0]
    bar = PipedProgress(40, "paper", interval=10.0, clock=lambda: now[0])
    assert capsys.readouterr().err == "paper: 0/40 frames\n"
    for _ in range(9):  # 9 frames in 9 s: no line yet
        now[0] += 1.0
        bar.update(1)
    assert capsys.readouterr().err == ""
    now[0] += 1.0
    bar.update(1)
    bar.set_postfix_str("0000000009")
    assert capsys.readouterr().err == "paper: 10/40 frames (25 %), 1.0 frames/s\n"
    now[0] += 10.0
    bar.set_postfix_str("0000000010")  # a postfix alone reports too, once the interval has passed
    assert capsys.readouterr().err == "paper: 10/40 frames (25 %), 0.5 frames/s, 0000000010\n"
    bar.close()
    now[0] += 60.0
    bar.update(30)
    assert capsys.readouterr().err == "" and bar.n == 40


def test_progress_bar_is_tqdm_on_a_terminal_lines_on_a_pipe_and_nothing_with_q(monkeypatch):
    import io
    import sys

    from tqdm import tqdm

    from lanegraph.runlog import PipedProgress, progress_bar

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    monkeypatch.setattr(sys, "stderr", Terminal())
    bar = progress_bar(3, "paper")
    assert isinstance(bar, tqdm) and not bar.disable
    bar.close()
    monkeypatch.setattr(sys, "stderr", io.StringIO())
    assert isinstance(progress_bar(3, "paper"), PipedProgress)
    assert sys.stderr.getvalue() == "paper: 0/3 frames\n"
    quiet = progress_bar(3, "paper", enabled=False)
    assert isinstance(quiet, tqdm) and quiet.disable
    assert sys.stderr.getvalue() == "paper: 0/3 frames\n"


def test_a_piped_run_says_it_has_started_and_q_keeps_it_quiet(tmp_path):
    import subprocess
    import sys

    env = dict(os.environ, LANEGRAPH_PRECOMPILE="0")
    cmd = [sys.executable, "-m", "lanegraph.cli", "run", "--frames", "0:2"]
    loud = subprocess.run([*cmd, "--out", str(tmp_path / "a")], capture_output=True, text=True, env=env)
    assert loud.returncode == 0, loud.stderr
    assert "paper: 0/2 frames" in loud.stderr.splitlines()
    quiet = subprocess.run(
        [*cmd, "--out", str(tmp_path / "b"), "-q"], capture_output=True, text=True, env=env
    )
    assert quiet.returncode == 0, quiet.stderr
    assert "frames" not in quiet.stderr
