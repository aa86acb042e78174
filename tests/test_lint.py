"""ruff (configured in pyproject.toml: pyflakes and pycodestyle's errors and warnings) finds nothing in the
repository: an unused name, an undefined one, an import shadowed by a loop variable fail the suite."""

import subprocess
import sys
from pathlib import Path


def test_ruff_finds_nothing():
    root = Path(__file__).resolve().parents[1]
    res = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", str(root)], capture_output=True,
                         text=True, cwd=root)
    assert res.returncode == 0, res.stdout + res.stderr
