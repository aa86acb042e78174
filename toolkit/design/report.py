"""The design report, drawn only from what ``evstab design`` wrote (``evstab report DIR`` redraws it).

Inputs in ``DIR``: ``design.json``, ``sweep.csv``, ``analysis.csv``, ``poles.csv``,
``responses.csv``, ``limits.csv``. Outputs: ``report.md`` with PNGs under
``figures/`` and ``report.html`` with the same content and the figures embedded
(self-contained), and ``summary.md`` (:func:`summary_table`). Both are rendered from one list of blocks, so they cannot
disagree; every number is formatted by :func:`fmt`.
"""

from __future__ import annotations

import base64
import html
import io
import json
from pathlib import Path

import numpy as np

from ..logs.drivelog import atomic_write, read_rows_csv
from .record import design_points

NEEDED = ("design.json", "sweep.csv", "analysis.csv", "poles.csv", "responses.csv", "limits.csv")


def fmt(v) -> str:
    """Numbers as the report prints them (4 significant digits), booleans as yes/no."""
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        if not np.isfinite(v):
            return str(v)
        if 1e4 <= abs(float(v)) < 1e9:  # a large number in full (34729, not 3.473e+04)
            return f"{v:.0f}"
        return f"{v:.4g}"
    return str(v)


class Doc:
    def __init__(self):
        self.blocks: list[tuple] = []

    def h(self, level: int, text: str):
        self.blocks.append(("h", level, text))

    def p(self, text: str):
        self.blocks.append(("p", text))

    def verdict(self, lines: list[str]):
        """A boxed summary (a blockquote in Markdown)."""
        self.blocks.append(("verdict", lines))

    def table(self, rows: list[dict], cols: list[str] | None = None, headers: list[str] | None = None):
        if not rows:
            self.p("(no rows)")
            return
        cols = cols or list(rows[0])
        self.blocks.append(("table", headers or cols, [[fmt(r.get(c, "")) for c in cols] for r in rows]))

    def figure(self, name: str, fig, caption: str):
        import matplotlib.pyplot as plt
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=100, bbox_inches="tight")
        plt.close(fig)
        self.blocks.append(("fig", name, buf.getvalue(), caption))

    def markdown(self) -> str:
        out = []
        for b in self.blocks:
            if b[0] == "h":
                out.append("#" * b[1] + " " + b[2] + "\n")
            elif b[0] == "p":
                out.append(b[1] + "\n")
            elif b[0] == "verdict":
                out.append("\n".join(f"> {line}  " for line in b[1]) + "\n")
            elif b[0] == "table":
                hdr, rows = b[1], b[2]
                out.append("| " + " | ".join(hdr) + " |\n|" + "---|" * len(hdr))
                out.extend("| " + " | ".join(c.replace("|", "/") for c in r) + " |" for r in rows)
                out.append("")
            else:
                out.append(f"![{b[3]}](figures/{b[1]}.png)\n\n*{b[3]}*\n")
        return "\n".join(out) + "\n"

    def html(self, title: str) -> str:
        out = [f"<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>{html.escape(title)}</title>",
               "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222}"
               "table{border-collapse:collapse;margin:1em 0;font-size:0.85em}td,th{border:1px solid #bbb;"
               "padding:2px 6px;text-align:right}th{background:#eee}img{max-width:100%}"
               "figcaption{font-style:italic;color:#555}.verdict{border:2px solid #333;padding:0.3em 1em;"
               "background:#f6f6f0}.verdict p{margin:0.4em 0}</style></head><body>"]
        for b in self.blocks:
            if b[0] == "h":
                out.append(f"<h{b[1]}>{html.escape(b[2])}</h{b[1]}>")
            elif b[0] == "p":
                out.append(f"<p>{html.escape(b[1])}</p>")
            elif b[0] == "verdict":
                out.append("<div class=\"verdict\">" + "".join(f"<p>{html.escape(x)}</p>" for x in b[1]) + "</div>")
            elif b[0] == "table":
                out.append("<table><tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in b[1]) + "</tr>")
                out.extend("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in b[2])
                out.append("</table>")
            else:
                data = base64.b64encode(b[2]).decode()
                out.append(f"<figure><img alt=\"{html.escape(b[3])}\" src=\"data:image/png;base64,{data}\">"
                           f"<figcaption>{html.escape(b[3])}</figcaption></figure>")
        out.append("</body></html>")
        return "\n".join(out)


def load_outputs(d: Path) -> dict:
    missing = [n for n in NEEDED if not (d / n).is_file()]
    if missing:
        raise FileNotFoundError(f"{d}: not a design directory, missing {', '.join(missing)} "
                                f"(run 'evstab design --out {d}' first)")
    return {"design": json.loads((d / "design.json").read_text()), "sweep": read_rows_csv(d / "sweep.csv"),
            "analysis": read_rows_csv(d / "analysis.csv"), "poles": read_rows_csv(d / "poles.csv"),
            "responses": read_rows_csv(d / "responses.csv"), "limits": read_rows_csv(d / "limits.csv")}


def param_unit(name: str) -> str:
    """The unit of a vehicle parameter, from its field documentation (``[...]`` at the end)."""
    import re
    from dataclasses import fields

    from evstab.plants.params import VehicleParams
    doc = next((f.metadata.get("doc", "") for f in fields(VehicleParams) if f.name == name), "")
    m = re.search(r"\[([^\]]+)\]\s*$", doc)
    return m.group(1) if m else "-"


CASE_HEADERS = ("front stiffness x [-]", "rear stiffness x [-]", "mu [-]", "mass x [-]", "yaw inertia x [-]",
                "speed [km/h]", "GPS rate [Hz]", "GPS latency [s]")
"""The sweep case columns ``cf_scale, cr_scale, mu, mass_scale, inertia_scale, speed_kmh, gps_rate,
gps_latency`` as the report's tables head them (``x``: a factor on the nominal value)."""


def cost_sentence() -> str:
    """What the sweep's ``cost`` measures (:func:`toolkit.design.sweep.cost_of`), with the scales the code uses."""
    from .sweep import B_SCALE, E_SCALE, R_SCALE, U_WEIGHT
    return ("Cost of a case (dimensionless; the tuning minimises its worst case): the mean over the standard "
            "manoeuvres of the mean-square yaw-rate tracking error over "
            f"({np.degrees(R_SCALE):g} deg/s)^2, plus the mean-square sideslip tracking error over "
            f"({np.degrees(B_SCALE):g} deg)^2, plus the mean-square sideslip estimation error over "
            f"({np.degrees(E_SCALE):g} deg)^2, plus {U_WEIGHT:g} x the mean-square yaw moment over the square of the largest "
            "the motors make: a cost of 1 is, for example, a yaw-rate tracking error of "
            f"{np.degrees(R_SCALE):g} deg/s RMS and nothing else.")


def _case_text(r: dict) -> str:
    parts = [f"mu {r['mu']:.2f}", f"{r['speed_kmh']:.0f} km/h"]
    for key, label in (("cf_scale", "front stiffness"), ("cr_scale", "rear stiffness"), ("mass_scale", "mass"),
                       ("inertia_scale", "yaw inertia")):
        if abs(r[key] - 1.0) > 1e-9:
            parts.append(f"{label} {100 * (r[key] - 1):+.0f} %")
    parts.append(f"GPS {r['gps_rate']:g} Hz")
    if r["gps_latency"]:
        parts.append(f"latency {1000 * r['gps_latency']:.0f} ms")
    return f"case {r['case_id']} ({r['group']}: " + ", ".join(parts) + ")"


def _gm(x: float) -> str:
    return "inf" if not np.isfinite(x) else f"{x:.1f}"


def margin_lines(s: dict, tuned: str) -> list[str]:
    """The verdict box's margin line: the tuned design's worst margins on its own model, against the
    constraint (:func:`toolkit.design.stability.margins_admissible`), and across the model errors beside the
    paper design's (reported, not constrained)."""
    from .stability import RobustMargins, margins_admissible
    mg, con = s.get("margins", {}), s.get("margin_constraint")
    if tuned not in mg or "paper" not in mg or not con:
        return []
    n, e = (RobustMargins(**mg[tuned][k]) for k in ("nominal", "model_error"))
    pe = RobustMargins(**mg["paper"]["model_error"])
    why = margins_admissible(n)
    speeds = f"{min(con['speeds_kmh']):g}-{max(con['speeds_kmh']):g} km/h"
    return [f"Margins ({speeds}, loop at a time at the plant inputs and outputs): on its own model disk margin "
            f"{n.disk_margin:.2f} (at least {con['disk_margin_min']:g}), sensitivity peak {n.sensitivity_peak:.2f} "
            f"(at most {con['sensitivity_peak_max']:g}); steer loop GM {_gm(n.gm_delta_db)} dB / PM "
            f"{n.pm_delta_deg:.0f} deg, yaw-moment loop GM {_gm(n.gm_nz_db)} dB / PM {n.pm_nz_deg:.0f} deg. "
            "Margin constraint met: " + fmt(not why) + ("" if not why else " (" + "; ".join(why) + ")") + ". "
            f"Across the model errors (not constrained) disk margin {e.disk_margin:.2f} ({e.where_disk}), "
            f"sensitivity peak {e.sensitivity_peak:.2f} (the paper design's {pe.disk_margin:.2f} and "
            f"{pe.sensitivity_peak:.2f})."]


def verdict_lines(doc: dict, by: dict, lim_by: dict, responses: list[dict], designs: list[str]) -> list[str]:
    """The first screen: stable or not, FMVSS 126 per friction, the limit rule, the weakest case."""
    s, tuned = doc["sweep"], designs[-1]
    lines = [f"Verdict for the {tuned} design" + (" (the paper design, unchanged: no tuned point met the limit "
                                                   "constraint)" if s.get("tuned_is_paper") else "") + "."]
    lines.append(f"Stable in {s[tuned]['stable_cases']} of {s['cases']} model-error cases (paper design "
                 f"{s['paper']['stable_cases']}); stable wherever the paper design is: "
                 f"{fmt(s['tuned_stable_where_paper_stable'])}.")
    fm = [c for c in lim_by.values() if c["no control"]["kind"] == "fmvss126"]
    if fm:
        lines.append("FMVSS 126: " + "; ".join(
            f"{c[tuned]['plant']} mu {c[tuned]['mu']:g} {'PASS' if c[tuned]['pass'] else 'FAIL'} "
            f"({c[tuned]['runs_passed']}/{c[tuned]['runs']} runs; no control {c['no control']['runs_passed']})"
            for c in fm) + ".")
    lim = s.get("limits", {}).get(tuned)
    if lim:
        lines.append(f"Limit manoeuvres: {lim['limit_runs_held']} of {lim['limit_runs']} runs hold the car; no worse "
                     "than no control in every one: " + fmt(lim["no_worse_than_no_control"])
                     + ("" if lim["no_worse_than_no_control"] else " (" + "; ".join(lim["worse_than_no_control"]) + ")")
                     + ".")
    lines += margin_lines(s, tuned)
    rows = by.get(tuned, {})
    if rows:
        w = rows[s[tuned]["worst_case_id"]]
        if not w["bounded"]:
            what = (f"the car is lost in the standard manoeuvres (sine lane change and step steer): peak sideslip "
                    f"{w['beta_max_deg']:.1f} deg, beyond the sweep's 20 deg bound")
        elif not w["linear_stable"]:
            what = f"the sampled loop with the estimator is unstable (spectral radius {w['spectral_radius']:.4g})"
        else:
            what = (f"yaw-rate tracking error {np.degrees(w['yaw_rate_rms_err']):.3g} deg/s RMS, sideslip estimation "
                    f"error {w['beta_rms_deg']:.3g} deg RMS, peak sideslip {w['beta_max_deg']:.3g} deg")
        lost = sum(1 for r in rows.values() if not r["stable"])
        lines.append(f"Weakest: {_case_text(w)}, cost {fmt(w['cost'])}: {what}"
                     + (f"; {lost} case(s) in all are not stable." if lost else "."))
    peaks: dict = {}
    for r in responses:
        if r["controller"] == tuned:
            k = (r["mu"], r["maneuver"])
            peaks[k] = max(peaks.get(k, 0.0), abs(r["beta"]))
    if peaks:
        (mu, man), b = max(peaks.items(), key=lambda kv: kv[1])
        lines.append(f"Largest sideslip of the {tuned} design in the time responses below: {np.degrees(b):.2f} deg "
                     f"({man} at 80 km/h on mu {mu:g}).")
    return lines


def build(data: dict) -> Doc:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import patheffects

    doc, sweep = data["design"], data["sweep"]
    s = doc["sweep"]
    points = design_points(doc)
    designs = list(points)
    veh = doc["vehicle"]
    D = Doc()
    D.h(1, f"evstab design report: {veh['name']}")
    D.p(f"Command: {doc['provenance']['command']}")

    D.h(2, "Result")
    lim = data["limits"]
    lim_by: dict = {}
    for r in lim:
        lim_by.setdefault(r["case"], {})[r["design"]] = r
    labels = ["no control"] + designs
    by: dict = {}
    for r in sweep:
        by.setdefault(r["design"], {})[r["case_id"]] = r
    D.verdict(verdict_lines(doc, by, lim_by, data["responses"], designs))
    D.p("FMVSS 126 sine with dwell at 80 km/h (runs passed of every amplitude and both directions; A is the "
        "hand-wheel angle for 0.3 g from the slowly increasing steer on the same surface), closed loop with the "
        "ECU as exported, not told the friction:")
    D.table([{"plant": c[next(iter(c))]["plant"], "mu": c["no control"]["mu"],
              "A [deg hand-wheel]": c["no control"]["A_deg"], "runs": c["no control"]["runs"],
              **{f"{n} passed": c[n]["runs_passed"] for n in labels},
              **{f"{n} passes": c[n]["pass"] for n in labels}}
             for c in lim_by.values() if c["no control"]["kind"] == "fmvss126"])
    ls = s.get("limits", {})
    sel = doc["tuning"].get("limit_selection", [])
    if s.get("tuned_is_paper"):
        D.p("The tuned design is the paper design, unchanged: no candidate of the tuning met the limit constraint "
            "and the margin (" + "; ".join(f"box x{fmt(t['bounds_factor'])}: {t['rejected_because']}" for t in sel)
            + ").")
    elif sel:
        t = next(t for t in sel if t["accepted"])
        where = ("the tuning's candidate" if t is sel[0] else
                 f"the candidate of the tuning run again with each parameter within a factor "
                 f"{fmt(t['bounds_factor'])} of the paper design's")
        D.p(f"The tuned design is {where}. Limit constraint: " + doc["tuning"]["limit_constraint"] + ".")
        D.table([{"box factor": t["bounds_factor"], "K_beta [rad/s]": t["k_beta"], "K_gamma [rad/s]": t["k_gamma"],
                  "worst cost": t["worst_cost"], "limit runs held": f"{t['limit_runs_passed']}/{t['limit_runs']}",
                  "accepted": t["accepted"], "why not": t["rejected_because"][:160] or "-"} for t in sel])
    for n in designs:
        if n in ls and not ls[n]["no_worse_than_no_control"]:
            D.p(f"{n} design worse than no control: " + "; ".join(ls[n]["worse_than_no_control"]))
    D.p("Peak sideslip [deg] in the limit manoeuvres (ISO 3888-1 with the path-following driver; step steer asking "
        "the nominal linear car for 1.5 mu g):")
    D.table([{"manoeuvre": case, **{f"{n}": c[n]["peak_beta_deg"] for n in labels},
              "tuned no worse than no control": c[designs[-1]]["no_worse_than_none"]}
             for case, c in lim_by.items() if c["no control"]["kind"] != "fmvss126"])
    D.p(f"Worst case over the {fmt(s['cases'])} model-error cases of the sweep: paper design cost "
        f"{fmt(s['paper']['worst_cost'])} (case {fmt(s['paper']['worst_case_id'])}), tuned design cost "
        f"{fmt(s['tuned']['worst_cost'])} (case {fmt(s['tuned']['worst_case_id'])}); tuned strictly better on the "
        f"worst case (by at least {fmt(100 * s['better_margin'])} %): {fmt(s['tuned_strictly_better_worst_case'])}.")
    D.p(f"Stable cases (multi-rate linear loop with the estimator stable and every rollout bounded): paper "
        f"{fmt(s['paper']['stable_cases'])} of {fmt(s['cases'])}, tuned {fmt(s['tuned']['stable_cases'])} of "
        f"{fmt(s['cases'])}; tuned stable in every case the paper design is stable: "
        f"{fmt(s['tuned_stable_where_paper_stable'])}; tuned cheaper in {fmt(s['tuned_better_cases'])} cases.")

    D.h(2, "Vehicle and design")
    p = veh["nominal_params"]
    keys = ["mass", "yaw_inertia", "lf", "lr", "cornering_stiffness_front", "cornering_stiffness_rear", "mu",
            "max_motor_torque", "track_rear", "wheel_radius", "steering_ratio"]
    D.table([{"parameter": k, "nominal value": p.get(k), "unit": param_unit(k)} for k in keys
             if p.get(k) is not None])
    D.p(f"Parameter-set hash {veh['params_digest']}; plant model {doc['plant_model']}; control period "
        f"{fmt(doc['control_period_s'])} s; GPS {fmt(doc['gps']['rate_hz'])} Hz, latency "
        f"{fmt(doc['gps']['latency_s'])} s (designed).")
    D.table([{"quantity": k, **{n: points[n][k] for n in designs}} for k in points["paper"]])
    D.p("K_beta, K_gamma: model-following poles [rad/s]; q_*: process-noise intensities of the DAKF. "
        "The paper design is seed 003's K_beta = K_gamma = 5 rad/s with evstab's hand-tuned dakf noise.")
    t = doc["tuning"]
    D.p(f"Tuning: {t['method']}. Decision variables: {t['decision_variables']}, each within a factor "
        f"{fmt(t['bounds_factor'])} of the paper design; sigma_min {fmt(t['sigma_min_1_s'])} 1/s. Cost: {t['cost']}.")
    D.table([{"round": i + 1, "box factor": r.get("bounds_factor", t["bounds_factor"]),
              "tuning cases": " ".join(str(c) for c in r["cases"]), "IPOPT iterations":
              r["iterations"], "status": r["status"], "worst of tuning cases, start": r["worst_start"],
              "worst of tuning cases, tuned": r["worst_tuned"], "worst of the sweep": r["sweep_worst_cost"],
              "stability lost (cases)": " ".join(str(c) for c in r["stability_lost_cases"]) or "-"}
             for i, r in enumerate(t["rounds"])])

    D.h(2, "Analysis across speed")
    an = data["analysis"]
    D.h(3, "Observability of the estimator")
    D.table([r for r in an if r["design"] == designs[-1]],
            ["speed_kmh", "observable", "observability_rank", "observability_sv_ratio", "unobservable", "riccati",
             "estimator_slowest_rate_1_s"])
    D.h(3, "Internal stability and margins")
    D.table(an, ["design", "speed_kmh", "internally_stable", "loop_margin_1_s", "multirate_stable",
                 "multirate_spectral_radius"],
            ["design", "speed [km/h]", "internally stable", "loop decay rate [1/s]", "multi-rate loop stable",
             "multi-rate spectral radius [-]"])
    D.table(an, ["design", "speed_kmh", "gm_delta_db", "pm_delta_deg", "gm_nz_db", "pm_nz_deg", "disk_margin_min",
                 "sensitivity_peak_max"],
            ["design", "speed [km/h]", "GM steer [dB]", "PM steer [deg]", "GM Nz [dB]", "PM Nz [deg]",
             "disk margin [-]", "sensitivity peak [-]"])
    D.p("Margins are loop-at-a-time at the plant inputs (steer delta, yaw moment Nz), other channel closed; disk "
        "margin and sensitivity peak are the smallest / largest over the four loop-breaking points. A negative "
        "gain margin in dB is not an instability: the loop is stable as designed and stays stable for any gain "
        "increase, but becomes unstable if that channel's gain is reduced by the stated amount (its loop gain "
        "crosses -180 deg above 0 dB, as a loop around an open-loop unstable or conditionally stable channel does); "
        "inf means no crossing.")
    poles = data["poles"]
    for plane, title in (("s", "Loop poles in the s-plane (controller + nominal bicycle plant)"),
                         ("z", "Multi-rate loop with the estimator: monodromy eigenvalues over one GPS period")):
        fig, axes = plt.subplots(1, len(designs), figsize=(11, 4.2), squeeze=False)
        for ax, dn in zip(axes[0], designs):
            pr = [r for r in poles if r["design"] == dn and r["plane"] == plane]
            sc = ax.scatter([r["re"] for r in pr], [r["im"] for r in pr], c=[r["speed_kmh"] for r in pr], s=18,
                            cmap="viridis", marker="x")
            if plane == "z":
                th = np.linspace(0, 2 * np.pi, 400)
                ax.plot(np.cos(th), np.sin(th), "k-", lw=0.6)
                ax.set_aspect("equal")
            else:
                ax.axvline(0, color="k", lw=0.6)
            ax.set_title(f"{dn}")
            # s-plane poles: decay rate and angular frequency; z-plane: eigenvalues over one GPS period
            ax.set_xlabel("Re s [1/s]" if plane == "s" else "Re z [-]")
            ax.set_ylabel("Im s [rad/s]" if plane == "s" else "Im z [-]")
            ax.grid(alpha=0.3)
        fig.colorbar(sc, ax=axes[0].tolist(), label="speed [km/h]")
        D.figure(f"poles_{plane}", fig, title)

    D.h(2, "Model-error sweep")
    D.p(cost_sentence())
    grid = [r for r in sweep if r["group"] in ("stiffness",)]
    cfs = sorted({r["cf_scale"] for r in grid})
    crs = sorted({r["cr_scale"] for r in grid})
    if cfs and crs:
        from matplotlib.colors import ListedColormap, LogNorm
        from matplotlib.patches import Patch
        vals = [float(r["beta_rms_deg"]) for r in grid if float(r["beta_rms_deg"]) > 0]
        norm = LogNorm(vmin=min(vals), vmax=max(vals)) if vals else None  # one scale for every design
        verdict_cmap = ListedColormap(["#d7301f", "#1a9850"])
        fig, axes = plt.subplots(2, len(designs), figsize=(10, 8), squeeze=False)
        for j, dn in enumerate(designs):
            for i, key in enumerate(("stable", "beta_rms_deg")):
                M = np.full((len(crs), len(cfs)), np.nan)
                for r in grid:
                    if r["design"] == dn:
                        M[crs.index(r["cr_scale"]), cfs.index(r["cf_scale"])] = float(r[key])
                ax = axes[i, j]
                if key == "stable":
                    ax.imshow(M, origin="lower", cmap=verdict_cmap, vmin=0, vmax=1, aspect="auto")
                    ax.legend(handles=[Patch(color="#1a9850", label="stable"), Patch(color="#d7301f", label="not stable")],
                              loc="upper center", bbox_to_anchor=(0.5, -0.18), ncol=2, fontsize=8)
                    ax.set_title(f"{dn}: stability verdict")
                else:
                    im = ax.imshow(M, origin="lower", cmap="magma_r", aspect="auto", norm=norm)
                    ax.set_title(f"{dn}: sideslip estimation RMS [deg]")
                    fig.colorbar(im, ax=ax, label="sideslip estimation RMS [deg]")
                    for (yy, xx), v in np.ndenumerate(M):
                        ax.text(xx, yy, f"{v:.2g}", ha="center", va="center", fontsize=7, color="k",
                                path_effects=[patheffects.withStroke(linewidth=2, foreground="w")])
                ax.set_xticks(range(len(cfs)), [f"{(c - 1) * 100:+.0f}%" for c in cfs])
                ax.set_yticks(range(len(crs)), [f"{(c - 1) * 100:+.0f}%" for c in crs])
                ax.set_xlabel("front cornering stiffness error [%]")
                ax.set_ylabel("rear cornering stiffness error [%]")
        fig.tight_layout()
        D.figure("sweep_heatmaps", fig, "Stiffness grid at 80 km/h, mu 1: stability verdict and sideslip "
                                        "estimation RMS (one colour scale for both designs)")
    groups = sorted({r["group"] for r in sweep})
    D.table([{"group": g, **{f"{dn} worst cost": max(r["cost"] for r in sweep if r["group"] == g and
                                                     r["design"] == dn) for dn in designs},
              **{f"{dn} stable": sum(r["stable"] for r in sweep if r["group"] == g and r["design"] == dn)
                 for dn in designs},
              "cases": sum(1 for r in sweep if r["group"] == g and r["design"] == designs[0])} for g in groups])
    if "paper" in by and "tuned" in by:
        ids = sorted(by["paper"])
        fig, ax = plt.subplots(figsize=(6, 5.5))
        xs = np.array([by["paper"][i]["cost"] for i in ids])
        ys = np.array([by["tuned"][i]["cost"] for i in ids])
        ax.loglog(xs, ys, "o", ms=4, alpha=0.7)
        lo, hi = min(xs.min(), ys.min()), max(xs.max(), ys.max())
        ax.plot([lo, hi], [lo, hi], "k--", lw=0.8)
        ax.set_xlabel("paper design cost [-]")
        ax.set_ylabel("tuned design cost [-]")
        ax.grid(alpha=0.3, which="both")
        D.figure("cost_paper_vs_tuned", fig, "Case by case: below the diagonal the tuned design is better")
        D.h(3, "Tuned vs paper, case by case (the 20 worst cases of the paper design)")
        worst = sorted(ids, key=lambda i: -by["paper"][i]["cost"])[:20]
        cols = ["cf_scale", "cr_scale", "mu", "mass_scale", "inertia_scale", "speed_kmh", "gps_rate", "gps_latency"]
        D.table([{"case": i, **{c: by["paper"][i][c] for c in cols},
                  "paper cost": by["paper"][i]["cost"], "tuned cost": by["tuned"][i]["cost"],
                  "paper stable": by["paper"][i]["stable"], "tuned stable": by["tuned"][i]["stable"],
                  "paper beta RMS deg": by["paper"][i]["beta_rms_deg"],
                  "tuned beta RMS deg": by["tuned"][i]["beta_rms_deg"]} for i in worst],
                headers=["case", *CASE_HEADERS, "paper cost [-]", "tuned cost [-]", "paper stable", "tuned stable",
                         "paper sideslip est. RMS [deg]", "tuned sideslip est. RMS [deg]"])
    D.p("The whole table (one row per case and design) is sweep.csv / sweep.parquet.")

    D.h(2, "Time responses (80 km/h): the standard manoeuvres, and a step steer at the limit")
    resp = data["responses"]
    combos = sorted({(r["mu"], r["maneuver"]) for r in resp}, key=lambda c: (-c[0], c[1]))
    fig, axes = plt.subplots(len(combos), 2, figsize=(11, 2.6 * len(combos)), squeeze=False)
    for i, (mu, man) in enumerate(combos):
        for label in sorted({r["controller"] for r in resp}):
            rr = [r for r in resp if r["mu"] == mu and r["maneuver"] == man and r["controller"] == label]
            tt = [r["t"] for r in rr]
            line, = axes[i, 0].plot(tt, np.degrees([r["yaw_rate"] for r in rr]), label=label)
            axes[i, 1].plot(tt, np.degrees([r["beta"] for r in rr]), label=label, color=line.get_color())
            if label != "no control":  # the reference each design tracks, dashed in its colour
                axes[i, 0].plot(tt, np.degrees([r["yaw_rate_ref"] for r in rr]), "--", lw=0.9,
                                color=line.get_color(), label=f"{label} reference")
                if "beta_ref" in rr[0]:
                    axes[i, 1].plot(tt, np.degrees([r["beta_ref"] for r in rr]), "--", lw=0.9,
                                    color=line.get_color())
        axes[i, 0].set_ylabel(f"mu {mu:g} {man}\nyaw rate [deg/s]", fontsize=8)
        axes[i, 1].set_ylabel("sideslip [deg]")
        for ax in axes[i]:
            ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("t [s]")
    fig.tight_layout()
    D.figure("responses", fig, "Yaw rate and sideslip with no control, the paper design and the tuned design; "
                               "dashed: each design's reference (yaw rate, sideslip)")
    from .limits import STEP_SATURATION
    D.p("Where the controller acts: the peak sideslip of each run and the peak yaw moment each design commands "
        "(0 N m: the law stayed off and the car drove as without control; the step steer at the limit asks the "
        f"nominal linear car for {STEP_SATURATION:g} mu g).")
    D.table(response_peaks(resp), headers=response_peak_headers(resp))

    D.h(2, "Provenance")
    pv = doc["provenance"]
    D.table([{"item": k, "value": v} for k, v in (("evstab version", pv["evstab_version"]),
                                                   ("git revision", pv["git_revision"]),
                                                   ("parameter-set hash", veh["params_digest"]),
                                                   ("command", pv["command"]), ("python", pv["python"]))])
    return D


def _controllers(resp: list[dict]) -> list[str]:
    """The response runs' controllers, "no control" first."""
    return sorted({r["controller"] for r in resp}, key=lambda n: (n != "no control", n))


def response_peaks(resp: list[dict]) -> list[dict]:
    """One row per response run (friction, manoeuvre): the peak |sideslip| [deg] of each controller and the
    peak |yaw moment| [N m] each design commanded."""
    rows = []
    for mu, man in sorted({(r["mu"], r["maneuver"]) for r in resp}, key=lambda c: (-c[0], c[1])):
        runs = {c: [r for r in resp if r["mu"] == mu and r["maneuver"] == man and r["controller"] == c]
                for c in _controllers(resp)}
        row = {"mu": mu, "maneuver": man}
        row.update({f"{c} beta": float(np.degrees(max(abs(r["beta"]) for r in rr))) for c, rr in runs.items()})
        row.update({f"{c} Nz": max(abs(r["yaw_moment"]) for r in rr) for c, rr in runs.items() if c != "no control"})
        rows.append(row)
    return rows


def response_peak_headers(resp: list[dict]) -> list[str]:
    """The column headers of :func:`response_peaks`, with units."""
    cs = _controllers(resp)
    return ["mu [-]", "manoeuvre", *[f"{c}: peak sideslip [deg]" for c in cs],
            *[f"{c}: peak yaw moment [N m]" for c in cs if c != "no control"]]


def summary_table(doc: dict) -> str:
    """``summary.md``: the paper design against the tuned design in one Markdown table (gains, noise
    intensities, worst and median cost, stable cases, FMVSS 126, the limit runs), from ``design.json``."""
    s, des = doc["sweep"], design_points(doc)

    def g(x):
        return f"{x:.4g}"

    def row(label, f):
        return [label] + [f(n) for n in ("paper", "tuned")]

    def fm(n):
        lim = s.get("limits", {}).get(n)
        if not lim:
            return "-"
        return ", ".join(f"{k}: {v}" for k, v in lim["fmvss126"].items()) + (" PASS" if lim["fmvss126_pass"] else " FAIL")

    def held(n):
        lim = s.get("limits", {}).get(n)
        return "-" if not lim else (f"{lim['limit_runs_held']} / {lim['limit_runs']}, "
                                    + ("yes" if lim["no_worse_than_no_control"] else "no"))

    rows = [row("K_beta, K_gamma [rad/s]", lambda n: f"{g(des[n]['k_beta'])}, {g(des[n]['k_gamma'])}"),
            row("q_beta, q_yaw_rate, q_d1, q_d2", lambda n: ", ".join(g(des[n][k]) for k in
                                                                   ("q_beta", "q_yaw_rate", "q_d1", "q_d2"))),
            row(f"worst-case cost over the {s['cases']} cases",
                lambda n: f"{g(s[n]['worst_cost'])} (case {s[n]['worst_case_id']})"),
            row("median cost", lambda n: g(s[n]["median_cost"])),
            row("stable cases", lambda n: f"{s[n]['stable_cases']} / {s['cases']}"),
            ["cases where the tuned design is cheaper by the margin", "", f"{s['tuned_better_cases']} / {s['cases']}"],
            row("FMVSS 126 runs passed", fm),
            row("limit runs held, no worse than no control", held)]
    lines = ["| | paper design | tuned design |", "| --- | --- | --- |"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def write_report(d) -> tuple[Path, Path]:
    """Draw ``report.md`` (+ ``figures/``), ``report.html`` and ``summary.md`` from the data in ``d``."""
    d = Path(d)
    data = load_outputs(d)
    atomic_write(d / "summary.md", lambda fh: fh.write(summary_table(data["design"])))
    D = build(data)
    for b in D.blocks:
        if b[0] == "fig":
            atomic_write(d / "figures" / f"{b[1]}.png", lambda fh, b=b: fh.write(b[2]), mode="wb")
    title = f"evstab design report: {data['design']['vehicle']['name']}"
    atomic_write(d / "report.md", lambda fh: fh.write(D.markdown()))
    atomic_write(d / "report.html", lambda fh: fh.write(D.html(title)))
    return d / "report.md", d / "report.html"
