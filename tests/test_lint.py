"""ruff (configured in pyproject.toml: pyflakes and pycodestyle's errors and warnings) and mypy (its
[tool.mypy] table: plants, controllers, toolkit, studies, benchmarks) find nothing in the repository: an
unused name, an undefined one, an import shadowed by a loop variable, an Optional used as if set, a value of
the wrong type fail the suite."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_ruff_finds_nothing():
    res = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", str(ROOT)], capture_output=True,
                         text=True, cwd=ROOT)
    assert res.returncode == 0, res.stdout + res.stderr


def test_mypy_finds_nothing(tmp_path):
    # a cache of its own: the run reads the tree as it is, and writes nothing into it
    res = subprocess.run([sys.executable, "-m", "mypy", "--cache-dir", str(tmp_path / "mypy")], capture_output=True,
                         text=True, cwd=ROOT)
    assert res.returncode == 0, res.stdout + res.stderr
