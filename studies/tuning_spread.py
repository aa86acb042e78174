"""How far the design job's tuning moves with rounding.

The design job's tuning (:func:`toolkit.design.tuning.tune`) on compact-ev with the job's own tuning set,
caps, starting FMVSS 126 displacement runs, margin constraint and starts (the full run's, or with ``--quick`` the
quick run's), once as built and again with its cost gradient multiplied by ``1 + 1e-12 N(0, 1)`` (seeded): a different
compiler, library or machine rounds differently, and IPOPT's path on these costs (spins in the
worst cases) moves with it. Per run: the tuned parameters, the tuning cases' worst cost (the
paper design's beside it) and the smallest FMVSS 126 lateral displacement of the held runs.
Writes ``tuning_spread.csv`` / ``.md``.

Run: ``python -m evstab.studies.tuning_spread OUT_DIR [--quick]`` (with ``--quick`` 25 min on 2
cores with four to six other jobs running).
"""

from __future__ import annotations

import numpy as np

from evstab.plants import load_vehicle
from evstab.studies._common import cli, out_dir, write_table
from evstab.toolkit.design import limits as lm, sweep as sw
from evstab.toolkit.design.selection import TUNING_STARTS, regression_caps, tuning_ids
from evstab.toolkit.design.rollout import RolloutCost
from evstab.toolkit.design.tuning import MarginConstraint, tune

PERTURBATION = 1e-12
"""Relative size of the gradient's perturbation: the order of the rounding two builds of the same
arithmetic differ by (forward against reverse mode: 4e-14)."""
SEEDS = (1, 2)


class _Perturbed:
    """Multiplies :meth:`RolloutCost.batch`'s gradients by ``1 + eps N(0, 1)`` while active."""

    def __init__(self, eps: float, seed: int):
        self.eps, self.rng, self.orig = eps, np.random.default_rng(seed), RolloutCost.batch

    def __enter__(self):
        orig, eps, rng = self.orig, self.eps, self.rng

        def batch(rc, phi, runs, rests):
            return [(c, g * (1.0 + eps * rng.standard_normal(g.shape))) for c, g in orig(rc, phi, runs, rests)]
        RolloutCost.batch = batch

    def __exit__(self, *exc):
        RolloutCost.batch = self.orig


def main(out, quick: bool = False) -> list[dict]:
    out = out_dir(out)
    cfg = sw.SweepConfig(load_vehicle("compact-ev"))
    cases = sw.sweep_cases(quick=quick)
    rows_paper = sw.run_sweep(cfg, cases, [cfg.paper], progress=False)
    a_cache: dict = {}
    none, paper = lm.run_limits(cfg, None, a_cache=a_cache), lm.run_limits(cfg, cfg.paper, a_cache=a_cache)
    displacement = lm.tightest(lm.displacement_runs(cfg, none, a_cache, also=paper), paper)
    ids = tuning_ids(cases, rows_paper, quick)
    caps = regression_caps(ids, rows_paper)
    margins = MarginConstraint.on_analysis_grid()
    rows = []
    for seed in (None,) + SEEDS:
        with _Perturbed(0.0 if seed is None else PERTURBATION, seed or 0):
            res = tune(cfg, [cases[i] for i in ids], cfg.paper, max_iter=12 if quick else 25, caps=caps,
                       displacement=displacement, starts=TUNING_STARTS, margins=margins)
        p = res.point
        rows.append({"gradient": "as built" if seed is None else f"x (1 + {PERTURBATION:g} N(0,1)), seed {seed}",
                     "k_beta": p.k_beta, "k_gamma": p.k_gamma, "q_beta": p.q_beta, "q_yaw_rate": p.q_yaw_rate,
                     "q_d1": p.q_d1, "q_d2": p.q_d2, "worst_paper": res.worst_start, "worst_tuned": res.worst_tuned,
                     "min_displacement_m": min(res.displacement_tuned) if res.displacement_tuned else float("nan"),
                     "iterations": res.iterations, "evaluations": res.evaluations})
    write_table(rows, out / "tuning_spread.csv", out / "tuning_spread.md", floatfmt="{:.4g}")
    return rows


if __name__ == "__main__":
    cli(main)
