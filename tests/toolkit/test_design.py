"""The design job: sweep vs single runs, casadi rollouts vs the numpy simulator, executors, report vs JSON."""

import json
from pathlib import Path
import shutil
import subprocess

import numpy as np
import pytest

from evstab.plants import TRUTH, load_vehicle
from evstab.plants.disturbances import Disturbances, Friction
from evstab.toolkit.design import sweep as sw
from evstab.toolkit.design.record import design_points
from evstab.toolkit.loop.closed_loop import EXTRA
from evstab.toolkit.loop.simulator import simulate

P = load_vehicle("compact-ev")
CFG = sw.SweepConfig(P)
TUNED = sw.DesignPoint("tuned", k_beta=2.0, k_gamma=12.0, q_beta=2e-5, q_yaw_rate=0.01, q_d1=0.005, q_d2=0.03)
# model errors of every kind at once, GPS at 20 Hz with three fixes in flight (150 ms)
CASE_A = sw.Case(0, cf_scale=0.8, cr_scale=1.2, mu=0.8, mass_scale=1.1, inertia_scale=0.9, speed_kmh=60.0,
                 gps_rate=20.0, gps_latency=0.15, gyro_bias=0.003, gyro_scale_error=0.01, group="test")
CASE_B = sw.Case(1, cf_scale=1.2, cr_scale=0.9, mu=0.7, speed_kmh=80.0, gps_rate=2.0, gps_latency=0.05,
                 group="test")


def _stepped(case: sw.Case, point: sw.DesignPoint, man):
    """The same case run by the simulator, from the design objects (not the sweep's inputs and calibration vector)."""
    true = case.plant_params(CFG.nominal)
    r = simulate(true, CFG.plant, man, disturbances=Disturbances(friction=Friction(mu=case.mu)),
                 sensors=case.sensors(CFG.sensors), seed=case.seed,
                 controller="two-dof", design=point.controller(CFG.base_design()),
                 estimator=CFG.filter_design(point), nominal=CFG.nominal)
    Y = np.column_stack([r.truth[k] for k in TRUTH])
    E = np.column_stack([r.commands[k] for k in EXTRA])
    return Y, E


@pytest.mark.parametrize("case", [CASE_A, CASE_B], ids=["all-errors-20Hz-150ms", "mu0.7-2Hz"])
def test_sweep_row_equals_direct_single_case_runs(case):
    row = sw.evaluate_case(CFG, case, [TUNED])[0]
    terms = [sw.cost_terms(*_stepped(case, TUNED, man)) for man in sw.standard_maneuvers(CFG, case.speed_kmh / 3.6)]
    nz_max = CFG.base_design().nz_max
    ms = {k: np.mean([t[k] for t in terms]) for k in terms[0]}
    # same equations and noise, evaluation order differs: rounding only (1e-9 relative)
    assert row["beta_rms_deg"] == pytest.approx(np.degrees(np.sqrt(ms["ms_est"])), rel=1e-9)
    assert row["yaw_rate_rms_err"] == pytest.approx(np.sqrt(ms["ms_r"]), rel=1e-9)
    assert row["cost"] == pytest.approx(np.mean([sw.cost_value(t, nz_max) for t in terms]), rel=1e-9)
    assert row["bounded"] and row["design"] == "tuned"
    for f in sw.CASE_FIELDS:
        assert row[f] == getattr(case, f)


def test_rollout_cost_and_gradient_equal_the_numpy_simulator():
    # the tuning's cost and gradient: the forward-mode lane kernel (the default with a compiler)
    from evstab.toolkit.design.rollout import RolloutCost
    from evstab.toolkit.design.tuning import phi_of
    rc = RolloutCost(CFG)
    assert rc.lanes is not None
    case = CASE_A
    _, runs = sw.case_inputs(CFG, case)
    rest = np.array([case.gyro_bias, case.gyro_scale_error, CFG.base_design().mu_max])  # the ECU is not told mu
    phi = phi_of(TUNED)
    man = sw.standard_maneuvers(CFG, case.speed_kmh / 3.6)[0]
    J, g = rc(phi, runs[0], rest)
    ref = sw.cost_value(sw.cost_terms(*_stepped(case, TUNED, man)), CFG.base_design().nz_max)
    assert J == pytest.approx(ref, rel=1e-9)  # differentiable casadi rollout = numpy simulator, rounding only
    # AD gradient vs central differences, step 1e-7 in log space: the ECU's tables are piecewise
    # linear in speed and the loop has branches (gating, saturation), so larger steps straddle kinks
    # (1e-5 differs by up to 1.2e-4); at 1e-7 truncation is ~1e-14 and rounding ~1e-16 / 1e-7, and
    # the difference agrees to 3.4e-6 (measured) -> 2e-5 relative
    for i in range(len(phi)):
        e = np.zeros(len(phi))
        e[i] = 1e-7
        fd = (rc(phi + e, runs[0], rest)[0] - rc(phi - e, runs[0], rest)[0]) / 2e-7
        assert g[i] == pytest.approx(fd, rel=2e-5, abs=1e-8 * abs(J))


def test_forward_mode_lanes_equal_casadis_reverse_mode_on_every_run():
    # the same step differentiated two ways: casadi's reverse mode through the mapaccum rollout (its
    # generated C) and the forward-mode lane kernel, four runs at once; the step's math differs by
    # the lane kernel's vector sin/atan (within 2 ulp) and the sums' order: 3.7e-14 (cost) and
    # 2.9e-14 (gradient) relative apart on these runs (measured) -> 1e-12
    from evstab.toolkit.design.rollout import RolloutCost
    from evstab.toolkit.design.tuning import phi_of
    fast, ref = RolloutCost(CFG), RolloutCost(CFG, lanes=False)
    assert fast.lanes is not None and ref.lanes is None
    runs, rests = [], []
    for c in (CASE_A, CASE_B, sw.Case(2, group="nominal")):
        for run in sw.case_inputs(CFG, c)[1]:
            runs.append(run)
            rests.append(np.array([c.gyro_bias, c.gyro_scale_error, CFG.base_design().mu_max]))
    phi = phi_of(TUNED)
    for (J, g), (J_ref, g_ref) in zip(fast.batch(phi, runs, rests), [ref(phi, r, q) for r, q in zip(runs, rests)]):
        assert J == pytest.approx(J_ref, rel=1e-12)
        np.testing.assert_allclose(g, g_ref, rtol=0, atol=1e-12 * np.abs(g_ref).max())


def test_dask_and_local_executors_give_identical_rows():
    pytest.importorskip("distributed")
    cases = [CASE_A, CASE_B, sw.Case(2, group="nominal")]
    local = sw.run_sweep(CFG, cases, [sw.PAPER, TUNED], workers=2, progress=False, batch=1)
    dask = sw.run_sweep(CFG, cases, [sw.PAPER, TUNED], executor="dask", workers=2, progress=False, batch=2)
    serial = sw.run_sweep(CFG, cases, [sw.PAPER, TUNED], workers=1, progress=False)
    assert local == dask == serial  # exact: same seeds, same compiled code, order restored


def test_workers_in_threads_of_one_process_give_the_serial_rows():
    # Dask's in-process cluster runs its workers as threads; the compiled loop releases the GIL, so
    # two blocks really run at once and must not share the rollouts' reused arrays
    from concurrent.futures import ThreadPoolExecutor
    cases = sw.sweep_cases(quick=True)[:8]
    halves = [cases[:4], cases[4:]]
    def rows(h):  # spectral_radius is NaN without the linear verdicts: compared as text
        return [{k: ("nan" if isinstance(v, float) and np.isnan(v) else v) for k, v in r.items()}
                for r in sw.evaluate_cases(CFG, h, [sw.PAPER], linear=False)]

    serial = [rows(h) for h in halves]
    for _ in range(3):  # a race shows on some runs, not necessarily on the first
        with ThreadPoolExecutor(2) as pool:
            assert list(pool.map(rows, halves)) == serial


def test_dask_with_a_scheduler_and_two_worker_processes_gives_the_local_rows():
    # a real scheduler on 127.0.0.1 and two worker processes (spawned: each imports evstab and loads
    # the compiled loop from the cache), started and stopped here; blocks of cases per task
    distributed = pytest.importorskip("distributed")
    cases = [CASE_A, CASE_B, sw.Case(2, group="nominal"), sw.Case(3, mu=0.5, group="mu")]
    local = sw.run_sweep(CFG, cases, [sw.PAPER, TUNED], workers=1, progress=False)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster:
        assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
        with distributed.Client(cluster) as client:
            pids = set(client.run(__import__("os").getpid).values())
        assert len(pids) == 2 and __import__("os").getpid() not in pids  # two processes, not this one
        rows = sw.run_sweep(CFG, cases, [sw.PAPER, TUNED], executor="dask", scheduler=cluster.scheduler_address,
                            progress=False, batch=2)
    assert rows == local  # exact: same seeds, same compiled code, order restored


def test_tuning_refuses_bounds_and_starts_it_cannot_use():
    from evstab.plants.errors import SettingsError
    from evstab.toolkit.design.tuning import tune
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(SettingsError, match="tuning bounds must be a finite number > 0"):
            tune(CFG, [CASE_A], bounds=bad)
    for bad in (0, -2, 1.5):
        with pytest.raises(SettingsError, match="tuning starts must be a whole number >= 1"):
            tune(CFG, [CASE_A], starts=bad)


def test_latch_schedule_refuses_more_fixes_in_flight_than_slots():
    from evstab.plants.sensors import SensorConfig, gps_fix_mask
    from evstab.toolkit.loop.closed_loop import latch_schedule
    t = np.arange(2000) * 1e-3
    fix = gps_fix_mask(t, SensorConfig(gps_rate=20.0))
    sched = latch_schedule(fix, 0.15, 1e-3)
    assert sched.shape == (8, 2000) and sched[:4].sum() == fix.sum() == sched[4:].sum()
    with pytest.raises(ValueError, match="fix periods"):
        latch_schedule(fix, 0.2, 1e-3)


def test_latch_schedule_captures_each_fix_lag_samples_early_in_its_slot():
    from evstab.plants.sensors import SensorConfig, gps_fix_mask
    from evstab.toolkit.loop.closed_loop import latch_schedule, latch_schedule_parts
    t = np.arange(2000) * 1e-3
    fix = gps_fix_mask(t, SensorConfig(gps_rate=20.0))
    ks = np.nonzero(fix)[0]
    sched = latch_schedule(fix, 0.15, 1e-3)
    want = np.zeros((8, 2000))
    for i, k in enumerate(ks):  # fix i: slot i mod 4, captured 150 samples before it arrives (not before 0)
        want[i % 4, max(k - 150, 0)] = 1.0
        want[4 + i % 4, k] = 1.0
    assert np.array_equal(sched, want)
    # written into an input matrix's columns: whatever they held is replaced
    U = np.full((2000, 8), 7.0)
    latch_schedule_parts(fix, 0.15, 1e-3, out=(U[:, :4], U[:, 4:]))
    assert np.array_equal(U.T, want)
    assert all(np.array_equal(a, b) for a, b in zip(latch_schedule_parts(fix, 0.15, 1e-3), (want[:4].T, want[4:].T)))


def test_quick_cases_cover_the_issue_ranges():
    cases = sw.sweep_cases(quick=False)
    cf = [c.cf_scale for c in cases]
    assert min(cf) == pytest.approx(0.6) and max(cf) == pytest.approx(1.4)
    assert min(c.mu for c in cases) == pytest.approx(0.3) and max(c.gps_rate for c in cases) == 20.0
    assert min(c.gps_rate for c in cases) == 1.0 and max(c.gps_latency for c in cases) == pytest.approx(0.15)
    assert {round(c.mass_scale, 6) for c in cases if c.group == "mass_scale"} == {0.8, 1.2}
    assert len({c.case_id for c in cases}) == len(cases)


# ----------------------------------------------------------------- the whole job (quick)
@pytest.fixture(scope="module")
def design_dir(quick_design_dir):
    return quick_design_dir  # tests/conftest.py: one quick design run shared by the suite


def test_design_outputs_and_the_tuned_design_beats_the_paper_or_says_it_is_unchanged(design_dir):
    from evstab.toolkit.logs.drivelog import read_rows_csv as read_csv
    doc = json.loads((design_dir / "design.json").read_text())
    rows = read_csv(design_dir / "sweep.csv")
    cases = sw.sweep_cases(quick=True)
    assert len(rows) == 2 * len(cases) and {r["design"] for r in rows} == {"paper", "tuned"}
    for key in ("stable", "beta_rms_deg", "yaw_rate_rms_err", "cost", "cf_scale", "mu", "gps_latency"):
        assert key in rows[0]
    by = {(r["case_id"], r["design"]): r for r in rows}
    paper_worst = max(r["cost"] for r in rows if r["design"] == "paper")
    tuned_worst = max(r["cost"] for r in rows if r["design"] == "tuned")
    assert doc["sweep"]["paper"]["worst_cost"] == paper_worst
    assert doc["sweep"]["tuned"]["worst_cost"] == tuned_worst
    if doc["sweep"]["tuned_is_paper"]:  # no candidate met the limit constraint: said so, and unchanged
        points = design_points(doc)
        assert tuned_worst == paper_worst and points["tuned"] == points["paper"]
    else:  # better by the stated margin
        assert tuned_worst < (1.0 - doc["sweep"]["better_margin"]) * paper_worst
    assert all(by[(c.case_id, "tuned")]["stable"] for c in cases if by[(c.case_id, "paper")]["stable"])
    # the FMVSS 126 runs the tuning held to the lateral displacement: at least the 4 with the least
    # margin per surface and steer direction, named once each
    held = doc["tuning"]["fmvss126_displacement_runs"]
    for mu in ("1", "0.6"):
        for side in ("left", "right"):
            assert sum(h.startswith(f"fmvss126 80 km/h mu {mu},") and h.endswith(side) for h in held) >= 4
    assert len(held) == len(set(held))
    import pyarrow.parquet as pq
    assert pq.read_table(design_dir / "sweep.parquet").num_rows == len(rows)


def test_design_json_loads_into_designs_that_match_it(design_dir):
    from evstab.toolkit.design.design_job import load_design
    d = load_design(design_dir)
    # the loaded controller is the design the tuning's limit selection accepted (written by another step)
    accepted = [r for r in d.document["tuning"]["limit_selection"] if r["accepted"]]
    if accepted:
        assert (d.controller.k_beta, d.controller.k_gamma) == (accepted[0]["k_beta"], accepted[0]["k_gamma"])
    assert d.point.k_beta == d.controller.k_beta and d.point.q_d1 == d.filter.noise.q_d1
    assert d.filter.method == "dakf"
    # the tuned gains and noise are in the file once, in the controller and the estimator
    assert "designs" not in d.document and set(d.document["paper_design"]) == set(sw.DesignPoint.TUNED)
    assert d.params.digest() == d.document["vehicle"]["params_digest"]


def test_a_design_without_a_reference_model_loads_with_the_static_one(tmp_path, design_dir):
    # a design.json written before the linear reference model was designed and checked with seed 003's static
    # reference through the lag: loading it must not change its law
    from evstab.toolkit.design.design_job import load_design
    doc = json.loads((design_dir / "design.json").read_text())
    assert doc["controller"]["reference_model"] == "linear"
    assert load_design(design_dir).controller.reference_model == "linear"
    del doc["controller"]["reference_model"]
    (tmp_path / "design.json").write_text(json.dumps(doc))
    assert load_design(tmp_path).controller.reference_model == "static"


def test_load_design_names_the_file_and_field(tmp_path, design_dir):
    from evstab.toolkit.design.design_job import load_design
    doc = json.loads((design_dir / "design.json").read_text())
    doc["format"] = "something-else"
    (tmp_path / "design.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=r"design\.json: field 'format'"):
        load_design(tmp_path)
    del doc["format"]
    doc["format"] = "evstab-design/1"
    del doc["controller"]
    (tmp_path / "design.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="missing field 'controller'"):
        load_design(tmp_path)


def test_report_numbers_are_the_design_json_numbers(design_dir):
    from evstab.toolkit.design.report import fmt
    doc = json.loads((design_dir / "design.json").read_text())
    md = (design_dir / "report.md").read_text()
    html = (design_dir / "report.html").read_text()
    s = doc["sweep"]
    import html as html_lib
    for text, esc in ((md, str), (html, html_lib.escape)):  # the HTML escapes quotes in the command line
        assert f"paper design cost {fmt(s['paper']['worst_cost'])}" in text
        assert f"tuned design cost {fmt(s['tuned']['worst_cost'])}" in text
        assert f"paper {fmt(s['paper']['stable_cases'])} of {fmt(s['cases'])}" in text
        points = design_points(doc)
        for k, v in points["tuned"].items():
            assert f"| {k} | {fmt(points['paper'][k])} | {fmt(v)} |" in md
        assert doc["vehicle"]["params_digest"] in text and esc(doc["provenance"]["command"]) in text
        # the verdict's margins are design.json's (the tuned design's worst on its own model and across
        # the model errors), and the tuning held the design to the constraint
        m = s["margins"]["tuned"]
        assert f"disk margin {m['nominal']['disk_margin']:.2f} (at least 0.5)" in text
        assert f"sensitivity peak {m['nominal']['sensitivity_peak']:.2f} (at most 2)" in text
        assert f"Across the model errors (not constrained) disk margin {m['model_error']['disk_margin']:.2f}" in text
        assert "Margin constraint met: yes" in text
    assert "data:image/png;base64," in html and "src=\"figures/" not in html  # self-contained
    for name in ("poles_s", "poles_z", "sweep_heatmaps", "responses", "cost_paper_vs_tuned"):
        assert (design_dir / "figures" / f"{name}.png").stat().st_size > 5000


def test_every_report_plot_names_its_axes_with_units(design_dir, monkeypatch):
    """Every plot of the report says what its axes measure, with a unit in brackets: each axis's y label
    (a colour bar's label), and an x label on it or on a plot below it in the same column (a column of
    plots shares its time axis). The report's sentence on what the cost measures uses the cost's own
    scales."""
    import re

    from evstab.toolkit.design import report
    unit = re.compile(r"\[[^\]]+\]")
    seen = {}
    figure = report.Doc.figure

    def capture(self, name, fig, caption):
        seen[name] = [(ax.get_xlabel(), ax.get_ylabel(), hasattr(ax, "_colorbar"), ax.get_position())
                      for ax in fig.axes]
        figure(self, name, fig, caption)

    monkeypatch.setattr(report.Doc, "figure", capture)
    doc = report.build(report.load_outputs(design_dir))
    assert {"poles_s", "poles_z", "sweep_heatmaps", "responses", "cost_paper_vs_tuned"} <= set(seen)
    for name, axes in seen.items():
        plots = [a for a in axes if not a[2]]
        for xl, yl, colorbar, pos in axes:
            if colorbar:
                assert unit.search(yl) or unit.search(xl), (name, "colour bar", xl, yl)
                continue
            assert unit.search(yl), (name, yl)
            below = [a for a in plots if abs(a[3].x0 - pos.x0) < 0.02 and a[3].y0 <= pos.y0 and unit.search(a[0])]
            assert unit.search(xl) or below, (name, xl)
    text = doc.markdown()
    assert report.cost_sentence() in text
    # the sentence states the scales sweep.cost_of divides by: 1 deg/s, 0.5 deg, 0.5 deg, weight 0.1
    assert (np.degrees(sw.R_SCALE), np.degrees(sw.B_SCALE), np.degrees(sw.E_SCALE), sw.U_WEIGHT) == \
        pytest.approx((1.0, 0.5, 0.5, 0.1))
    assert "over (1 deg/s)^2" in text and "over (0.5 deg)^2" in text and "plus 0.1 x" in text


def test_every_phase_of_the_design_job_shows_a_bar(design_dir, quick_design_stderr):
    """The quick design's stderr (tests/conftest.py keeps it): a bar for the sweep, for each design's limit
    manoeuvres, for the tuning (a count of evaluations, no total it would outrun) and for the margins, analysis
    and responses; and no tuning bar with a fixed total (IPOPT's evaluations exceed its iterations)."""
    text = quick_design_stderr
    for bar in ("sweep:", "limit manoeuvres, no control:", "limit manoeuvres, paper:",
                "tuning (3 IPOPT starts of up to 12 iterations):", "margins, analysis and responses:"):
        assert bar in text, bar
    assert "limit manoeuvres, the candidate K_beta" in text or "no candidate" in (design_dir / "design.json").read_text()
    tuning = [seg for seg in text.replace("\n", "\r").split("\r") if seg.startswith("tuning (")]
    assert tuning and not any("%|" in seg for seg in tuning)  # tqdm draws "NN%|" only for a bar with a total


def test_the_readme_prints_what_command_1_prints(design_dir, quick_design_stdout):
    """The README's transcript of command 1 is what the suite's run of the same job prints, line for line, but
    for the phases' durations and the output folder: a changed tuning, sweep or selection fails this."""
    import re
    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    start = readme.index("What command 1 prints after the install")
    block = readme[readme.index("```\n", start) + 4:]
    block = block[:block.index("```")]

    def norm(text):
        text = re.sub(r": [0-9.]+ s \(total [0-9.]+ s\)", ": _ s", text)
        return [re.sub(r"-> \S+report\.html", "-> report.html", ln.rstrip()) for ln in text.strip().splitlines()]
    assert norm(block) == norm(quick_design_stdout)


def test_the_responses_show_the_controller_acting(design_dir):
    """The report's time responses include a run where the controller acts: the limit set's step steer on
    mu 0.5, where the car alone slides past 10 deg and both designs hold it below 5 deg commanding a
    yaw moment beyond the quiet rule's 300 N m (measured on compact-ev: the car alone 89.7 deg, the
    paper design 1.94 deg with 567 N m); the report's table of peaks says so."""
    from evstab.toolkit.design import report
    from evstab.toolkit.design.design_job import LIMIT_RESPONSE_MU
    data = report.load_outputs(design_dir)
    peaks = {(r["mu"], r["maneuver"]): r for r in report.response_peaks(data["responses"])}
    limit = peaks[(LIMIT_RESPONSE_MU, "step-steer at the limit")]
    assert limit["no control beta"] > 10.0
    for dn in ("paper", "tuned"):
        assert limit[f"{dn} beta"] < 5.0 and limit[f"{dn} Nz"] > 300.0, (dn, limit)
    md = (design_dir / "report.md").read_text()
    assert "| mu [-] | manoeuvre | no control: peak sideslip [deg] |" in md
    assert f"| {report.fmt(LIMIT_RESPONSE_MU)} | step-steer at the limit | {report.fmt(limit['no control beta'])} |" in md


def test_report_command_redraws_the_same_report(design_dir, tmp_path):
    from evstab.toolkit.cli import main
    copy = tmp_path / "copy"
    shutil.copytree(design_dir, copy)
    (copy / "report.md").unlink()
    (copy / "report.html").unlink()
    assert main(["report", str(copy)]) == 0
    assert (copy / "report.md").read_text() == (design_dir / "report.md").read_text()
    assert main(["report", str(tmp_path / "nothing")]) == 2


def test_design_cli_rejects_a_scheduler_without_dask(tmp_path, capsys):
    from evstab.toolkit.cli import main
    assert main(["design", "--vehicle", "compact-ev", "--out", str(tmp_path), "--scheduler", "tcp://x:1"]) == 2
    assert "--scheduler needs --executor dask" in capsys.readouterr().err


def _chromium():
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        path = shutil.which(name)
        if path:
            return path
    return None


_PROBE = """<script>window.addEventListener('load', function () {
  var imgs = document.images, broken = 0;
  for (var i = 0; i < imgs.length; i++) { if (!(imgs[i].complete && imgs[i].naturalWidth > 0)) broken++; }
  var p = document.createElement('pre'); p.id = 'probe';
  p.textContent = 'PROBE ' + document.documentElement.scrollWidth + ' ' + window.innerWidth + ' ' + imgs.length + ' ' + broken;
  document.body.appendChild(p);
});</script>"""


def _browser_checks(exe, report: Path, tmp_path: Path) -> None:
    """At 1400 px: no horizontal scroll, every image loaded (a copy of the report with a probe script;
    the report itself carries no script); and a screenshot that is far from one flat colour."""
    probe = tmp_path / f"probe_{report.parent.name}.html"
    probe.write_text(report.read_text().replace("</body>", _PROBE + "</body>"))
    res = subprocess.run([exe, "--headless", "--no-sandbox", "--disable-gpu", "--window-size=1400,900",
                          "--virtual-time-budget=5000", "--dump-dom", probe.resolve().as_uri()],
                         capture_output=True, text=True, timeout=120)
    import re
    m = re.search(r"PROBE (\d+) (\d+) (\d+) (\d+)<", res.stdout)
    assert m, res.stderr[-2000:]
    scroll, inner, images, broken = map(int, m.groups())
    assert scroll <= inner, f"horizontal scroll: page {scroll} px wide in a {inner} px window"
    assert images >= 5 and broken == 0
    shot = tmp_path / f"shot_{report.parent.name}.png"
    res = subprocess.run([exe, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                          f"--screenshot={shot}", "--window-size=1400,3000", report.resolve().as_uri()],
                         capture_output=True, text=True, timeout=120)
    assert shot.is_file(), res.stderr[-2000:]
    import matplotlib.image
    img = matplotlib.image.imread(str(shot))
    assert img.shape[0] == 3000 and img.shape[1] == 1400
    # a rendered page has text, tables and figures: far from one flat colour
    assert float(np.std(img[..., :3])) > 0.05


def test_report_html_renders_in_headless_chromium(design_dir, tmp_path):
    exe = _chromium()
    if exe is None:
        pytest.skip("no Chromium on this machine (.ci/run installs it from the system packages)")
    _browser_checks(exe, design_dir / "report.html", tmp_path)


def test_report_of_a_commonroad_car_passes_the_browser_checks(tmp_path_factory, tmp_path):
    exe = _chromium()
    if exe is None:
        pytest.skip("no Chromium on this machine (.ci/run installs it from the system packages)")
    from evstab.toolkit.cli import main
    out = tmp_path_factory.mktemp("cr1") / "design"
    assert main(["design", "--vehicle", "commonroad-1", "--out", str(out), "--quick", "--no-progress"]) == 0
    text = (out / "report.md").read_text()
    # the first screen answers: stable?, FMVSS 126?, where weakest?
    head = text[:text.index("## Vehicle and design")]
    assert "model-error cases" in head and "FMVSS 126: two-track mu 1 " in head and "Weakest: case" in head
    _browser_checks(exe, out / "report.html", tmp_path)


def test_sweep_runs_on_the_multibody_car():
    # the sweep on commonroad-mb:1 with its bundled nominal: the car is the package's set whatever a
    # case says, so only friction, speed, GPS and gyro axes remain; a row equals direct runs
    cfg = sw.SweepConfig(load_vehicle("commonroad-1"), plant="commonroad-mb:1")
    cases = sw.sweep_cases(quick=True, plant=cfg.plant)
    assert [c.case_id for c in cases] == list(range(len(cases)))
    assert {c.group for c in cases} == {"stiffness", "mu", "gps_rate", "gps_latency", "speed_kmh", "random"}
    assert all(c.cf_scale == c.cr_scale == c.mass_scale == c.inertia_scale == 1.0 for c in cases)
    case = next(c for c in cases if c.group == "stiffness")  # the car itself, 80 km/h, mu 1
    row = sw.evaluate_case(cfg, case, [sw.PAPER])[0]
    costs = []
    for man in sw.standard_maneuvers(cfg, case.speed_kmh / 3.6):
        r = simulate(cfg.nominal, cfg.plant, man, disturbances=Disturbances(friction=Friction(mu=case.mu)),
                     sensors=case.sensors(cfg.sensors), seed=case.seed, controller="two-dof",
                     estimator=cfg.filter_design(sw.PAPER))
        Y = np.column_stack([r.truth[k] for k in TRUTH])
        E = np.column_stack([r.commands[k] for k in EXTRA])
        costs.append(sw.cost_value(sw.cost_terms(Y, E), cfg.base_design().nz_max))
    assert row["cost"] == pytest.approx(np.mean(costs), rel=1e-12)  # the same compiled loop: rounding only
    assert row["bounded"] and np.isfinite(row["spectral_radius"])
