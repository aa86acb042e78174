"""Shared fixtures. Every tolerance in this suite has its reason next to it."""

import numpy as np
import pytest

from evstab.plants import load_vehicle

VEHICLES = ("micro-ev", "sedan-000", "compact-ev")


@pytest.fixture(params=VEHICLES)
def vehicle(request):
    return load_vehicle(request.param)


@pytest.fixture
def compact():
    return load_vehicle("compact-ev")


@pytest.fixture
def rng():
    return np.random.default_rng(20261121)


@pytest.fixture(scope="session")
def default_design_dir(tmp_path_factory):
    """A design folder of compact-ev's ECU with the default filter (``dakf``, the ECU's noise) and 2-DOF law
    on the nominal model, written directly (no design job): what the firmware tests export."""
    import json

    from evstab.toolkit.design.design_job import default_design_document

    doc = default_design_document("test fixture")
    out = tmp_path_factory.mktemp("default_design")
    (out / "design.json").write_text(json.dumps(doc, indent=2))
    return out


def progress_transcript(out):
    """Where the shared quick design run's stderr (its progress bars) is kept: beside its folder."""
    return out.parent / (out.name + "-stderr.txt")


def printed_transcript(out):
    """Where the shared quick design run's stdout (what command 1 prints) is kept: beside its folder."""
    return out.parent / (out.name + "-stdout.txt")


@pytest.fixture(scope="session")
def quick_design_stdout(quick_design_dir):
    """What the shared quick design run printed (command 1's transcript)."""
    return printed_transcript(quick_design_dir).read_text()


@pytest.fixture(scope="session")
def quick_design_stderr(quick_design_dir):
    """What the shared quick design run wrote to stderr: its progress bars."""
    return progress_transcript(quick_design_dir).read_text()


@pytest.fixture(scope="session")
def quick_design_dir(tmp_path_factory, request):
    """``evstab design --quick`` on compact-ev, run once for every test that needs a real design folder
    (once per run: with pytest-xdist's workers, the first to need it makes it in their common temporary
    folder while the others wait on a lock, then all read it). Its progress bars go to
    ``progress_transcript(out)``."""
    from contextlib import redirect_stderr, redirect_stdout

    from evstab.toolkit.cli import main

    def design(out):
        with open(progress_transcript(out), "w") as err, redirect_stderr(err), \
                open(printed_transcript(out), "w") as printed, redirect_stdout(printed):
            assert main(["design", "--vehicle", "compact-ev", "--out", str(out), "--quick"]) == 0
        return out

    if not hasattr(request.config, "workerinput"):  # not a pytest-xdist worker
        return design(tmp_path_factory.mktemp("quick_design"))
    import fcntl
    root = tmp_path_factory.getbasetemp().parent  # common to the workers of this run
    out, done = root / "quick_design", root / "quick_design.done"
    with open(root / "quick_design.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            if not done.exists():
                design(out)
                done.touch()
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
    return out
