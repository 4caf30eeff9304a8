"""The built-in graphs and dataset files live in ``graphs/`` at the repository's root; the wheel
installs them as ``lanegraph/graphs/`` (found by :mod:`lanegraph.builtin` from any folder). Every
other setting is in pyproject.toml."""

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent


class BuildPyWithGraphs(build_py):
    """build_py, then ``graphs/**/*.yaml`` copied to ``<build>/lanegraph/graphs/``."""

    def run(self):
        super().run()
        src = ROOT / "graphs"
        if not src.is_dir() or getattr(
            self, "editable_mode", False
        ):  # an editable install reads graphs/ in place
            return
        dst = Path(self.build_lib) / "lanegraph" / "graphs"
        for f in sorted(src.rglob("*.yaml")):
            target = dst / f.relative_to(src)
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(f, target)


setup(cmdclass={"build_py": BuildPyWithGraphs})
