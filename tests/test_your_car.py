"""docs/your-car.md is followed as a newcomer would: its vehicle file written, its simulate and estimate commands
and its Python snippet run in an empty folder, their printed lines compared with the page's; every other
command on the page parsed by evstab's own command line (a misspelt option or a missing argument fails). The
design, export and replay outputs come from the same commands run once by hand (the design takes minutes; the
suite's quick design covers the job itself)."""

import re
import shlex
import subprocess
import sys
from pathlib import Path

from evstab.toolkit.cli import build_parser, main

PAGE = Path(__file__).resolve().parents[1] / "docs" / "your-car.md"


def _blocks(lang):
    return re.findall(rf"```{lang}\n(.*?)```", PAGE.read_text(), flags=re.S)


def _commands():
    """``(command, printed lines)`` of each ``$ evstab ...`` in the page's console blocks."""
    out = []
    for block in _blocks("console"):
        lines = block.strip().splitlines()
        for i, ln in enumerate(lines):
            if ln.startswith("$ "):
                printed = []
                for nxt in lines[i + 1:]:
                    if nxt.startswith("$ "):
                        break
                    printed.append(nxt)
                out.append((ln[2:], printed))
    return out


def test_every_command_on_the_page_is_one_evstab_takes():
    cmds = _commands()
    assert len(cmds) >= 5  # simulate, estimate, design, export, replay
    parser = build_parser()
    for cmd, _ in cmds:
        argv = shlex.split(cmd)
        assert argv[0] == "evstab", cmd
        parser.parse_args(argv[1:])  # SystemExit (a test failure) on an unknown option or a missing argument


def test_simulate_and_estimate_print_what_the_page_shows(tmp_path, monkeypatch, capsys):
    (toml,) = _blocks("toml")
    monkeypatch.chdir(tmp_path)
    Path("my-hatch.toml").write_text(toml)
    ran = 0
    for cmd, printed in _commands():
        argv = shlex.split(cmd)
        if argv[1] not in ("simulate", "estimate"):
            continue
        capsys.readouterr()
        assert main(argv[1:]) == 0, cmd
        # the same arithmetic on the same machine prints the same digits; the page's figures are
        # rounded to two decimals, so this holds wherever the compiled loops run (x86-64)
        assert capsys.readouterr().out.strip().splitlines() == printed, cmd
        ran += 1
    assert ran == 2
    snippet = next(b for b in _blocks("python") if "beta_true" in b)
    res = subprocess.run([sys.executable, "-c", snippet], capture_output=True, text=True, check=True)
    shown = [b for b in _blocks("console") if b.startswith("sideslip error")]
    assert res.stdout.strip() == shown[0].strip()

