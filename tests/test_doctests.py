"""The Examples sections of the public API's docstrings run as doctests: what they print is what the code
returns (numpydoc's convention; every name ``import evstab`` offers for a script is reached through one)."""

import doctest
import importlib

import pytest

MODULES = ("evstab.plants.params", "evstab.plants.maneuvers", "evstab.plants.bicycle", "evstab.toolkit.loop.simulator")


@pytest.mark.parametrize("name", MODULES)
def test_the_examples_run(name):
    module = importlib.import_module(name)
    finder = doctest.DocTestFinder(exclude_empty=True)
    runner = doctest.DocTestRunner(optionflags=doctest.NORMALIZE_WHITESPACE)
    tests = [t for t in finder.find(module, name) if t.examples]
    assert tests, f"{name} has no Examples"
    for t in tests:
        runner.run(t)
    result = runner.summarize(verbose=False)
    assert result.failed == 0, f"{name}: {result.failed} of {result.attempted} examples failed"
