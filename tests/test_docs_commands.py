"""Every documented command runs as written: the shell blocks of README.md and docs/*.md (the
convention is in ``tests/_doc_shell.py``: ``bash``/``sh``/``shell``/``console`` blocks run,
``<!-- needs: REASON -->`` skips one with its reason, ``<!-- notest -->`` marks text that is not a
command).

Each page runs in a fresh folder that looks like a checkout (the repository's files linked in, no
``out/``), its blocks in order in one shell (a variable set in one block is there in the next),
stopping at the first command that fails, which is named by its page and line. The synthetic
scene is the only data. The kernels compiled once serve every page (the machine's kernel cache).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from . import _doc_shell as ds

ROOT = ds.ROOT
PAGES = [p for p in ds.doc_files() if any(b.lang in ds.SHELL_LANGS for b in ds.parse(p))]
#: what a page's checkout holds: the repository's own files (never out/, a build or a cache)
CHECKOUT = ("README.md", "pyproject.toml", "setup.py", "MANIFEST.in", "lanegraph", "plugins", "graphs",
            "docs", "benchmarks", "tests", ".ci")  # fmt: skip
#: the longest a page may take (a page that needs more gives its commands fewer frames)
PAGE_TIMEOUT_S = 900


def _checkout(tmp: Path) -> Path:
    work = tmp / "checkout"
    work.mkdir()
    for name in CHECKOUT:
        if (ROOT / name).exists():
            (work / name).symlink_to(ROOT / name)
    return work


def _where(stderr: str, where: dict[int, str]) -> str:
    for line in reversed(stderr.splitlines()):
        if line.startswith("@@failed "):
            numbers = [int(x) for x in line.split()[1:]]
            n = numbers[-1] if len(numbers) > 1 and numbers[-1] > 0 else numbers[0]
            near = [k for k in where if k <= n]
            return where[max(near)] if near else "?"
    return "?"


@pytest.mark.slow
@pytest.mark.parametrize("page", PAGES, ids=[p.relative_to(ROOT).as_posix() for p in PAGES])
def test_the_commands_of_a_page_run_in_order(page, tmp_path):
    blocks = ds.parse(page)
    text, where = ds.script(blocks, ROOT / "tests" / "_doc_shell.py")
    skipped = [f"{b.id} ({b.needs})" for b in blocks if b.lang in ds.SHELL_LANGS and b.needs is not None]
    if not where:
        pytest.skip(f"every command block needs what the test has not: {', '.join(skipped)}")
    from importlib import metadata

    paths = [os.environ.get("PYTHONPATH", "")]
    for name, folder in ds.local_projects(blocks).items():
        try:
            metadata.distribution(name)  # installed, as .ci/run does
        except metadata.PackageNotFoundError:  # found as if installed: its entry points, its package
            paths[:0] = [str(p) for p in ds.stand_in_install(name, ROOT / folder, tmp_path / "site")]
    work = _checkout(tmp_path)
    env = {
        # a user's fresh shell: no MLflow setting that an earlier test's in-process tracker left behind
        # (mlflow.set_tracking_uri sets MLFLOW_TRACKING_URI in this process's environment)
        **{k: v for k, v in os.environ.items() if not k.startswith("MLFLOW_")},
        "PATH": os.pathsep.join([str(Path(sys.executable).parent), os.environ.get("PATH", "")]),
        "BROWSER": "true",  # `--open` opens nothing
        "TMPDIR": str(tmp_path / "tmp"),  # what a command leaves in the temporary folder is seen
        "LANEGRAPH_CACHE_DIR": str(tmp_path / "cache"),  # the result cache; the kernels stay shared
        "MPLBACKEND": "Agg",
        "PYTHONPATH": os.pathsep.join(p for p in paths if p),
    }
    (tmp_path / "tmp").mkdir()
    proc = subprocess.run(
        ["bash", "-c", text], cwd=work, env=env, capture_output=True, text=True, timeout=PAGE_TIMEOUT_S
    )
    if proc.returncode != 0:
        pytest.fail(
            f"{_where(proc.stderr, where)}: the command exited {proc.returncode}\n"
            f"--- stdout (end)\n{proc.stdout[-3000:]}\n--- stderr (end)\n{proc.stderr[-5000:]}",
            pytrace=False,
        )
    left = sorted(p.name for p in (tmp_path / "tmp").iterdir())
    assert not left, f"{page.name}: the commands left {left} in the temporary folder"


# --------------------------------------------------------------------------- the convention itself
def _blocks():
    return [b for p in ds.doc_files() for b in ds.parse(p)]


def test_every_skip_says_why():
    bare = [b.id for b in _blocks() if b.needs is not None and not b.needs.strip()]
    assert not bare, f"<!-- needs: REASON --> without a reason: {bare}"


def test_no_command_hides_in_an_untagged_block():
    """A block that is not tagged as shell but starts like a command would never run: tag it
    ``bash`` (or mark it ``<!-- notest -->`` when it shows output)."""
    hidden = []
    for b in _blocks():
        if b.lang in ("", "text") and not b.notest and b.lines:
            first = b.lines[0].lstrip("$ ").split(" ")[0]
            if first in ("lanegraph", "pip", "python", "python3", "ruff", "dask", "mlflow"):
                hidden.append(b.id)
    assert not hidden, f"commands in untagged blocks (tag them bash, or mark them <!-- notest -->): {hidden}"


def test_the_script_runs_blocks_in_order_and_names_lines(tmp_path):
    page = tmp_path / "p.md"
    page.write_text(
        "```bash\nX=1\n```\n\n<!-- needs: a GPU -->\n```bash\nexit 3\n```\n\n"
        "```console\n$ test $X = 1\nsome output\n$ python -c 'raise SystemExit(3)'\n```\n\n<!-- notest -->\n```bash\nexit 4\n```\n"
    )
    blocks = ds.parse(page, tmp_path)
    assert [(b.needs, b.notest) for b in blocks] == [
        (None, False),
        ("a GPU", False),
        (None, False),
        (None, True),
    ]
    text, where = ds.script(blocks, ROOT / "tests" / "_doc_shell.py")
    proc = subprocess.run(["bash", "-c", text], capture_output=True, text=True)
    assert proc.returncode == 3 and _where(proc.stderr, where) == "p.md:13"
    assert "exit 3" not in text and "exit 4" not in text and "some output" not in text


def test_pip_install_is_checked_not_run():
    assert ds.fake_pip(["install", "-e", ".[test]"]) == 0
    assert ds.fake_pip(["install", "-e", ".[no_such_extra]"]) == 2
    assert ds.fake_pip(["install", "lanegraph[dev]"]) == 0
    assert ds.fake_pip(["uninstall", "lanegraph"]) == 2


def test_the_readme_says_what_each_extra_adds():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    missing = [e for e in sorted(ds.extras()) if f"| `{e}` |" not in text]
    assert not missing, f"README.md's extras table lacks {missing}"
    # CI installs the project as the README tells developers to, and runs the README's test command
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert 'pip install -q -e ".[dev]"' in ci and 'pip install -e ".[dev]"' in text
    assert "python -m pytest -q\n" in ci
