"""Sideslip estimators: designs, the multi-rate Kalman step, baselines, runners, analysis."""

from .runner import Estimate, compiled_filter, run_estimator
from .spec import METHODS, FilterDesign, NoiseSettings, design_filter

__all__ = ["METHODS", "Estimate", "FilterDesign", "NoiseSettings", "compiled_filter", "design_filter",
           "run_estimator"]
