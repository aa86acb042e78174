"""The design record: what ``design.json`` holds and how its designs are read back.

The tuned design's gains and noise intensities are written once, in the document's ``controller`` and
``estimator`` sections (what the firmware is exported from); ``paper_design`` records the paper design it is
compared with. :func:`design_points` gives both as :data:`toolkit.design.sweep.DesignPoint.TUNED` values.
"""

from __future__ import annotations

from .sweep import DesignPoint

FORMAT = "evstab-design/2"
READS = ("evstab-design/1", FORMAT)
"""The formats :func:`toolkit.design.design_job.load_design` reads: ``/1`` also wrote the tuned design's gains and noise in ``designs.tuned``,
beside the controller and the estimator that hold them."""


def design_points(doc: dict) -> dict:
    """``{"paper": {...}, "tuned": {...}}``: the paper design's gains and noise intensities
    (:data:`toolkit.design.sweep.DesignPoint.TUNED`) as the document records them, and the tuned design's as its
    controller and estimator hold them (written there alone)."""
    paper = doc["paper_design"] if "paper_design" in doc else doc["designs"]["paper"]
    ctl, noise = doc["controller"], doc["estimator"]["noise"]
    tuned = {k: float(ctl[k] if k in ctl else noise[k]) for k in DesignPoint.TUNED}
    return {"paper": dict(paper), "tuned": tuned}
