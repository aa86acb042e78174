"""Compiled kernels: step functions traced with casadi and compiled to C (:mod:`.compiled`), and the lane
kernels that step many cases per call on vector types (:mod:`.lanes`, their C in :mod:`.lane_math`). It imports
nothing else of the toolkit; plants, estimators, the loop and the design run on it.
"""
