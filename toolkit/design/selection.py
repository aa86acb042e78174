"""The design job's choice of the tuned design: the tuning with cutting-plane rounds over the sweep,
and the limit constraint that accepts a candidate or tunes again (:mod:`toolkit.design.design_job` runs
them; :mod:`toolkit.design.tuning` is the optimisation, :mod:`toolkit.design.limits` the limit manoeuvres)."""

from __future__ import annotations

import dataclasses

import numpy as np

from . import sweep as sw

BETTER_MARGIN = 0.05
"""A design is better than another on a cost when it is lower by at least this share of it."""


TUNING_STARTS = 3
"""IPOPT runs per tuning (:func:`toolkit.design.tuning.tune`'s ``starts``)."""
CUT_ROUNDS = 2
"""Cutting-plane rounds per box of :func:`limit_constrained` (displacement runs the candidate missed)."""
TRUST_RADII = (1.0, 0.5, 0.25)
"""Half-widths (log space) of the boxes around the paper design that the tuning runs in again, one
after the other, when its candidate fails the limit check: each parameter within a factor e^1
(2.7), e^0.5 (1.6) and e^0.25 (1.3) of the paper design's (the first tuning's box is
:data:`toolkit.design.tuning.BOUNDS`, e^2)."""


def margin_plants(cfg, cases) -> list:
    """The plants the margins are taken on besides the design's own model: the sweep cases' distinct
    plant parameters (model errors), labelled by the first case that has them."""
    seen: dict = {}
    for c in cases:
        q = c.plant_params(cfg.nominal)
        seen.setdefault(q.digest(), (f"case {c.case_id} ({c.group})", q))
    return list(seen.values())


def design_margins(cfg, point, cases=None) -> dict:
    """A design point's worst margins (:func:`toolkit.design.stability.robust_margins`) over the speed grid of
    the analysis: ``{"nominal": on its own model, "model_error": across the sweep's plants}`` (without
    ``cases``, the first only: what the margin constraint judges)."""
    from .analysis import SPEEDS_KMH
    from .stability import robust_margins
    ctl = point.controller(cfg.base_design())
    out = {"nominal": robust_margins(ctl, [("its own model", cfg.nominal)], SPEEDS_KMH)}
    if cases is not None:
        out["model_error"] = robust_margins(ctl, margin_plants(cfg, cases), SPEEDS_KMH)
    return out


def tuning_ids(cases, rows_paper, quick):
    """The first tuning set: the paper design's worst cases, the hardest cases it still holds and
    the nominal case."""
    n_tune, n_keep = (2, 2) if quick else (4, 8)
    ranked = sorted(rows_paper, key=lambda r: -r["cost"])
    nominal_id = next(c.case_id for c in cases if c.cf_scale == 1.0 and c.cr_scale == 1.0 and c.group == "stiffness")
    ids = [r["case_id"] for r in ranked[:n_tune]]
    ids += [r["case_id"] for r in ranked if r["stable"]][:n_keep]  # the hardest cases the paper design holds
    ids.append(nominal_id)
    return list(dict.fromkeys(ids))  # once each (a worst case may be one the paper design holds)


def regression_caps(ids, rows_paper) -> list[float]:
    """Per tuning case, the cap on its cost: ``REGRESS_FACTOR`` times the paper design's plus
    ``REGRESS_OFFSET`` where the paper design holds the case, none (``inf``) where it does not."""
    from .tuning import REGRESS_FACTOR, REGRESS_OFFSET
    by = {r["case_id"]: r for r in rows_paper}
    return [REGRESS_FACTOR * by[i]["cost"] + REGRESS_OFFSET if by[i]["stable"] else float("inf") for i in ids]


def tune_rounds(cfg, cases, rows_paper, quick, executor, scheduler, workers, progress, log, *, ids=None,
                 bounds=None, displacement=None):
    """Tuning with cutting-plane rounds over the sweep, within ``bounds`` (log space; default
    :data:`toolkit.design.tuning.BOUNDS`) around the paper design.

    Round 1 tunes on ``ids`` (default :func:`tuning_ids`), with the FMVSS 126 runs ``displacement``
    (:func:`toolkit.design.limits.displacement_runs`) and the margin constraint (on the design's own model) as
    constraints. After each
    round the candidate is swept; cases where the paper design is stable and the
    candidate is not, and the candidate's worst case, join the tuning set, and the
    next round starts again from the paper design (feasible for every cap). The result is the candidate with the
    smallest worst-case cost among those stable wherever the paper design is stable
    (the paper design itself if no candidate is).

    Returns ``(point, its sweep rows, the rounds' records, the tuning set as it ended)``.
    """
    from .tuning import BOUNDS, MarginConstraint, tune
    paper = cfg.paper
    margins = MarginConstraint.on_analysis_grid()
    bounds = BOUNDS if bounds is None else bounds
    max_iter, max_rounds = (12, 2) if quick else (25, 3)
    paper_by = {r["case_id"]: r for r in rows_paper}
    paper_worst = max(r["cost"] for r in rows_paper)
    ids = list(tuning_ids(cases, rows_paper, quick) if ids is None else ids)
    start, rounds, best = paper, [], None
    for k in range(max_rounds):
        res = tune(cfg, [cases[i] for i in ids], start, max_iter=max_iter, caps=regression_caps(ids, rows_paper),
                   bounds=bounds,
                   displacement=displacement, starts=TUNING_STARTS, margins=margins,
                   workers=workers if executor == "local" else None, progress=progress)
        cand = dataclasses.replace(res.point, name="tuned")
        rows = sw.run_sweep(cfg, cases, [cand], executor=executor, scheduler=scheduler, workers=workers,
                            progress=progress)
        lost = [r["case_id"] for r in rows if paper_by[r["case_id"]]["stable"] and not r["stable"]]
        worst = max(rows, key=lambda r: r["cost"])
        rounds.append(dict(bounds_factor=float(np.exp(bounds)), cases=list(res.cases), iterations=res.iterations,
                           status=res.status, worst_start=res.worst_start, worst_tuned=res.worst_tuned,
                           sweep_worst_cost=worst["cost"], stability_lost_cases=lost))
        log(f"  tuning round {k + 1} (each parameter within x{np.exp(bounds):.3g} of the paper design's): "
            f"{res.iterations} IPOPT iterations, tuning cases' worst {res.worst_tuned:.4g}; worst case of the "
            f"sweep {worst['cost']:.4g} (paper "
            f"{paper_worst:.4g}), stability lost in {len(lost)} case(s)")
        ok = not lost
        if ok and (best is None or worst["cost"] < best[2]):
            best = (cand, rows, worst["cost"])
        if ok and worst["cost"] < paper_worst:  # what the design must achieve; further rounds cost minutes
            break
        lost_sorted = sorted(lost, key=lambda i: -next(r["cost"] for r in rows if r["case_id"] == i))
        new = [i for i in lost_sorted + [worst["case_id"]] if i not in ids]
        if not new:
            break
        ids.extend(new)
        # the next round starts from the paper design again: it meets every cap by construction
        # (a candidate that lost a case violates that case's cap, an infeasible start)
    if best is None:  # no candidate kept every stable case: keep the paper design's gains
        rows = [dict(r, design="tuned") for r in rows_paper]
        best = (dataclasses.replace(paper, name="tuned"), rows, paper_worst)
    return best[0], best[1], rounds, ids


def limit_constrained(cfg, cases, rows_paper, cand, rows_cand, retune, limits_start, log, progress: bool = False):
    """The tuned design under the limit constraint (:mod:`toolkit.design.limits`).

    The tuning's candidate is driven through the limit manoeuvres; it is accepted when it is no
    worse than no control on every limit case where the paper design is no worse (case by case,
    :func:`toolkit.design.limits.newly_worse`), passes FMVSS 126 and
    as many limit runs as the paper design, loses no case of the sweep the paper design holds,
    beats the paper design's worst case by :data:`BETTER_MARGIN` and meets the margin constraint
    (:func:`toolkit.design.stability.margins_admissible`; the tuning holds its candidates to it already). Otherwise the tuning runs again
    (``retune(radius, missed)`` returns a candidate and its sweep rows, or None when ``missed``
    names no run it could hold that it does not hold already), and each candidate is checked the
    same way; the first accepted is the tuned design:

    * a candidate that misses FMVSS 126's lateral displacement in runs the tuning did not hold is
      tuned again in the same box with those runs held (a cutting plane), up to
      :data:`CUT_ROUNDS` times per box;
    * then in smaller boxes around the paper design (:data:`TRUST_RADII`): an optimum in a smaller
      box, not a point on the way back to one candidate, which would hang on where one IPOPT
      path ended.

    None accepted: the paper design, unchanged (and the summary says so).

    ``limits_start``: ``(limit rows of no control, of the paper design, the FMVSS 126 A cache)``.

    Returns ``(point, sweep rows, limit rows of no control / paper / tuned, selection log)``."""
    from . import limits as lm
    from .stability import margins_admissible
    from .tuning import BOUNDS
    none, paper_lim, a_cache = limits_start
    last: dict = {}
    jp = lm.judge(paper_lim, none)
    paper_worst = max(r["cost"] for r in rows_paper)
    paper_stable = {r["case_id"] for r in rows_paper if r["stable"]}
    tried = []

    def is_paper(point):
        return all(getattr(point, k) == getattr(cfg.paper, k) for k in sw.DesignPoint.TUNED)

    def check(point, rows, radius):
        entry = {"bounds_factor": float(np.exp(radius)), "k_beta": point.k_beta, "k_gamma": point.k_gamma,
                 "worst_cost": max(r["cost"] for r in rows)}
        if is_paper(point):  # the tuning kept no candidate: nothing to drive
            tried.append({**entry, "admissible": jp["admissible"], "fmvss126_pass": jp["fmvss126_pass"],
                          "limit_runs_passed": jp["limit_runs_passed"], "limit_runs": jp["limit_runs"],
                          "accepted": False, "rejected_because": "the tuning kept no candidate (every one lost a "
                                                                 "case the paper design holds): the paper design"})
            log(f"  limit check, box x{np.exp(radius):.3g}: no candidate")
            last["missed"] = []
            return None
        lim = lm.run_limits(cfg, point, a_cache=a_cache, progress=progress,
                            label=f"the candidate K_beta {point.k_beta:.4g}")
        last["missed"] = lm.missed_displacement(lim, none)
        j = lm.judge(lim, none)
        worst = entry["worst_cost"]
        lost = sorted(r["case_id"] for r in rows if r["case_id"] in paper_stable and not r["stable"])
        why = []
        newly = lm.newly_worse(lim, paper_lim)
        if newly:  # case by case: where the paper design is no worse than no control, the candidate must not be
            why.append("worse than no control: " + "; ".join(newly))
        if jp["fmvss126_pass"] and not j["fmvss126_pass"]:
            why.append("fails FMVSS 126")
        if j["limit_runs_passed"] < jp["limit_runs_passed"]:
            why.append(f"{j['limit_runs_passed']} of {j['limit_runs']} limit runs held "
                       f"(paper {jp['limit_runs_passed']})")
        if lost:
            why.append(f"loses stability in sweep case(s) {' '.join(map(str, lost))}")
        if not worst < (1.0 - BETTER_MARGIN) * paper_worst:
            why.append(f"worst cost {worst:.4g} not {BETTER_MARGIN:.0%} below the paper design's {paper_worst:.4g}")
        why += ["margins: " + w for w in margins_admissible(design_margins(cfg, point)["nominal"])]
        tried.append({**entry, "admissible": j["admissible"], "fmvss126_pass": j["fmvss126_pass"],
                      "limit_runs_passed": j["limit_runs_passed"], "limit_runs": j["limit_runs"],
                      "accepted": not why, "rejected_because": "; ".join(why)})
        log(f"  limit check, the candidate of the box x{np.exp(radius):.3g} (K_beta {point.k_beta:.4g}, K_gamma "
            f"{point.k_gamma:.4g}): " + ("accepted" if not why else "rejected, " + "; ".join(why)))
        return (point, rows, none + paper_lim + lim) if not why else None

    found = check(cand, rows_cand, BOUNDS)
    for radius in (BOUNDS,) + TRUST_RADII:
        if radius != BOUNDS and found is None:
            last["missed"] = []
            point, rows = retune(radius, [])
            found = check(point, rows, radius)
        for _ in range(CUT_ROUNDS):
            if found is not None or not last.get("missed"):
                break
            got = retune(radius, last.pop("missed"))
            if got is None:
                break
            found = check(got[0], got[1], radius)
        if found is not None:
            break
    if found is not None:
        return (*found, tried)
    point = dataclasses.replace(cfg.paper, name="tuned")
    return (point, [dict(r, design="tuned") for r in rows_paper],
            none + paper_lim + [dict(r, design="tuned") for r in paper_lim], tried)
