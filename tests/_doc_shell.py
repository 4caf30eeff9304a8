"""The shell commands of the docs, as the executed-docs test (``tests/test_docs_commands.py``) runs
them: which blocks run, the script one document's blocks make, and the stand-ins for the few
commands that must not run inside the test.

Convention (every page of README.md and docs/*.md): a fenced block tagged ``bash``, ``sh``,
``shell`` or ``console`` runs (in a ``console`` block the lines starting with ``$`` are the
commands, the rest is their output); an HTML comment on the line(s) just above it changes that:

- ``<!-- needs: REASON -->``: the block needs what the test has not (a cluster, a GPU, downloaded
  KITTI data, the developers' ``../shared`` data): skipped with that reason;
- ``<!-- notest -->``: the block is not a command (a file's text, output shown).

Run as a script (``python tests/_doc_shell.py pip|python ARGS``) it is the stand-in the documents'
scripts call for ``pip`` and ``python``: ``pip install`` is checked (the extras it names exist, the
folder it installs is a project) and not run, the test runs in the environment CI installed;
``python -m pytest`` without a path (the whole suite, which CI runs anyway) is not run inside it;
every other ``python`` command runs as written.
"""

from __future__ import annotations

import os
import re
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHELL_LANGS = ("bash", "sh", "shell", "console")
_FENCE = re.compile(r"^```\s*([\w+-]*)\s*$")
_MARKER = re.compile(r"^<!--\s*(?P<kind>notest|needs:|from:)\s*(?P<arg>.*?)\s*-->$")


def doc_files(root: Path = ROOT) -> list[Path]:
    """Every page whose commands run: README.md, docs/*.md and the example distributions' READMEs
    (a page added later is picked up as it is)."""
    return sorted({root / "README.md", *root.glob("docs/*.md"), *root.glob("docs/examples/*/README.md")})


@dataclass
class ShellBlock:
    doc: str  # repository-relative path of the page
    line: int  # 1-based line of the block's first code line
    lang: str
    lines: list[str]
    needs: str | None = None  # why it is skipped
    notest: bool = False
    source: str | None = None  # ``<!-- from: PATH -->``: the file it is an excerpt of

    @property
    def text(self) -> str:
        """The block's code, as one string ending in a newline."""
        return "\n".join(self.lines) + "\n"

    @property
    def id(self) -> str:
        return f"{self.doc}:{self.line}"

    def commands(self) -> list[tuple[int, str]]:
        """``(line in the page, text)`` of the lines to run (a ``console`` block: its ``$`` lines)."""
        out = []
        for k, text in enumerate(self.lines):
            if self.lang == "console":
                if not text.startswith("$"):
                    continue
                text = text[1:].lstrip()
            out.append((self.line + k, text))
        return out


def parse(path: Path, root: Path = ROOT) -> list[ShellBlock]:
    """The fenced blocks of a page, with the markers just above each (``tests/test_docs.py`` and
    the executed-docs test read pages through this one parser): the blocks tagged as shell, and every
    other block too (``lang`` as tagged: the python and yaml blocks test_docs runs and validates, and
    the check that no command hides in an untagged block)."""
    rel = path.relative_to(root).as_posix()
    lines = path.read_text(encoding="utf-8").splitlines()
    blocks: list[ShellBlock] = []
    i = 0
    while i < len(lines):
        m = _FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        needs, notest, source = None, False, None
        j = i - 1
        while j >= 0 and (not lines[j].strip() or _MARKER.match(lines[j].strip())):
            mk = _MARKER.match(lines[j].strip())
            if mk and mk["kind"] == "needs:":
                needs = mk["arg"] or ""
            elif mk and mk["kind"] == "notest":
                notest = True
            elif mk and mk["kind"] == "from:":
                source = source or mk["arg"].split()[0]
            j -= 1
        end = i + 1
        while end < len(lines) and lines[end].rstrip() != "```":
            end += 1
        assert end < len(lines), f"{rel}:{i + 1}: unclosed code fence"
        blocks.append(ShellBlock(rel, i + 2, m.group(1).lower(), lines[i + 1 : end], needs, notest, source))
        i = end + 1
    return blocks


def script(blocks: list[ShellBlock], helper: Path) -> tuple[str, dict[int, str]]:
    """One bash script of the blocks that run, in order, and ``{script line: "page:line"}``."""
    head = [
        "set -eEuo pipefail",
        f'pip() {{ python3_lg {shlex.quote(str(helper))} pip "$@"; }}',
        f'python() {{ python3_lg {shlex.quote(str(helper))} python "$@"; }}',
        f'python3_lg() {{ {shlex.quote(sys.executable)} "$@"; }}',
        # in a stand-in function LINENO is the function's line; the last of BASH_LINENO is the page's
        "trap 'echo \"@@failed $LINENO ${BASH_LINENO[*]:-}\" >&2' ERR",
    ]
    where: dict[int, str] = {}
    body: list[str] = []
    for b in blocks:
        if b.lang not in SHELL_LANGS or b.notest or b.needs is not None:
            continue
        body.append(f"echo '@@block {b.id}' >&2")
        for line, text in b.commands():
            body.append(text)
            where[len(head) + len(body)] = f"{b.doc}:{line}"
    return "\n".join(head + body) + "\n", where


def local_projects(blocks: list[ShellBlock], root: Path = ROOT) -> dict[str, str]:
    """``{distribution name: folder}`` of the projects in the repository that the blocks that run
    ``pip install`` (the stand-in checks, it does not install: the test needs them installed)."""
    out = {}
    for b in blocks:
        if b.lang not in SHELL_LANGS or b.notest or b.needs is not None:
            continue
        for _, text in b.commands():
            if not text.lstrip().startswith("pip install"):
                continue
            try:
                words = shlex.split(text, comments=True)
            except ValueError:  # a line that goes on below (a quote or a backslash open)
                words = text.split()
            for w in words[2:]:
                toml = root / w / "pyproject.toml"
                if not w.startswith("-") and toml.is_file():
                    m = re.search(r'^name\s*=\s*"([^"]+)"', toml.read_text(encoding="utf-8"), re.M)
                    if m:
                        out[m.group(1)] = w
    return out


def stand_in_install(name: str, folder: Path, site: Path) -> list[Path]:
    """What ``pip install -e FOLDER`` gives lanegraph, without installing: a distribution named
    ``name`` with FOLDER's ``lanegraph.plugins`` entry points, in ``site``. Returns the folders to
    put on PYTHONPATH (``site`` and FOLDER, where its package lies)."""
    text = (folder / "pyproject.toml").read_text(encoding="utf-8")
    section = text.split('[project.entry-points."lanegraph.plugins"]', 1)[1].split("\n[", 1)[0]
    points = re.findall(r'^([\w.-]+)\s*=\s*"([^"]+)"', section, re.M)
    info = site / f"{name.replace('-', '_')}-0.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 0.0\n")
    (info / "entry_points.txt").write_text(
        "[lanegraph.plugins]\n" + "".join(f"{k} = {v}\n" for k, v in points)
    )
    return [site, folder]


# --------------------------------------------------------------------------- the stand-ins
def extras(root: Path = ROOT) -> set[str]:
    """The extras pyproject.toml declares (the keys of ``[project.optional-dependencies]``)."""
    text = (root / "pyproject.toml").read_text(encoding="utf-8")
    section = text.split("[project.optional-dependencies]", 1)[1].split("\n[", 1)[0]
    return set(re.findall(r"^([\w-]+)\s*=", section, re.M))


def fake_pip(args: list[str]) -> int:
    """``pip install ...``: what it names checked, nothing installed."""
    if not args or args[0] != "install":
        print(f"doc test: pip {' '.join(args)}: only `pip install` is expected in the docs", file=sys.stderr)
        return 2
    known = extras()
    for spec in (a for a in args[1:] if not a.startswith("-")):
        m = re.fullmatch(r"(?P<what>[^\[\]]+)(\[(?P<extras>[\w,\-]+)\])?", spec)
        if m is None:
            print(f"doc test: pip install {spec}: not a requirement", file=sys.stderr)
            return 2
        what, wanted = m["what"], [e for e in (m["extras"] or "").split(",") if e]
        if what in (".", "lanegraph"):
            unknown = [e for e in wanted if e not in known]
            if unknown:
                print(f"doc test: pip install {spec}: no extra {unknown} in pyproject.toml", file=sys.stderr)
                return 2
        elif "/" in what or what.startswith("."):
            if not (Path(what) / "pyproject.toml").is_file() and not Path(what).is_file():
                print(f"doc test: pip install {spec}: no project there", file=sys.stderr)
                return 2
    print(f"doc test: pip {' '.join(args)}: checked, not run (the environment is CI's)", file=sys.stderr)
    return 0


def fake_python(args: list[str]) -> int:
    """``python ...`` as written, except the whole test suite (``python -m pytest`` with no path)."""
    if args[:2] == ["-m", "pytest"] and not [a for a in args[2:] if not a.startswith("-")]:
        print(
            "doc test: python -m pytest: the whole suite, which CI runs: not run inside it", file=sys.stderr
        )
        return 0
    os.execv(sys.executable, [sys.executable, *args])
    return 0  # pragma: no cover - execv does not return


if __name__ == "__main__":
    tool, rest = sys.argv[1], sys.argv[2:]
    sys.exit(fake_pip(rest) if tool == "pip" else fake_python(rest))
