"""A compile says what it compiles and how long it took (on a terminal, or with EVSTAB_PROGRESS=1), once: the
cached library is loaded silently the next time."""

import casadi as ca

from evstab.toolkit.kernels import compiled


def _fn():
    x = ca.SX.sym("x", 2)
    return ca.Function("twice", [x], [2 * x])


def test_a_cold_compile_prints_a_line(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("EVSTAB_CACHE", str(tmp_path))
    monkeypatch.setenv("EVSTAB_PROGRESS", "1")
    key = compiled.cache_key("est", "a test filter")
    assert compiled.compile_library([_fn()], key) is not None
    err = capsys.readouterr().err
    assert err.startswith("evstab: compiling the estimator to C (first run with this code and model only; cached "
                          f"in {tmp_path})") and err.rstrip().endswith(" s"), err
    assert compiled.compile_library([_fn()], key) is not None  # cached: loaded, nothing said
    assert capsys.readouterr().err == ""


def test_silent_when_not_asked(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("EVSTAB_CACHE", str(tmp_path))
    monkeypatch.setenv("EVSTAB_PROGRESS", "0")
    assert compiled.compile_library([_fn()], compiled.cache_key("loop", "x")) is not None
    assert capsys.readouterr().err == ""
    assert compiled.compile_notice(compiled.cache_key("loop_lanes", "y")) is None
    monkeypatch.setenv("EVSTAB_PROGRESS", "1")
    assert "the closed loop's lane kernel" in compiled.compile_notice(compiled.cache_key("loop_lanes", "y"))
    assert "a plant model" in compiled.compile_notice("0123456789abcdef0123")  # a plant's key has no prefix
