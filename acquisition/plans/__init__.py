"""Plans: what a capture does, as data and generators, before any device is touched.

``messages`` (what a plan may ask: ``Move``, ``Read``, ``Dark``, ...), ``generators`` (the capture's plans:
``measure_points``, ``calibrate``, ``adaptive``, ``final_dark``, ``capture``; ``acquisition.plans.measure_points``
is the name the examples use), ``plan`` (``Plan``: a grid of points and its checks), ``planconfig`` (the bench
file's ``[plan]``), ``geometry`` (what the arms can reach; ``Reason``), ``ordering`` (short arm travel),
``refine`` (adaptive refinement's criterion) and ``reference`` (is the white reference plausible, before the
sweep). Imports the bench file's types and calibration, never a driver or
the run (``Plan.estimate`` asks the dry run only when called).
"""

from __future__ import annotations

import importlib

#: The names of :mod:`acquisition.plans.generators`, served here (``acquisition.plans.measure_points``) when first
#: used: importing a room's module (``acquisition.plans.planconfig`` for the bench file) loads no plan machinery.
_GENERATORS = ("PlanGen", "PointsPlan", "PlanSpec", "RoundEstimate", "Sample", "point", "measure", "measure_points",
               "white_reference", "rereference", "calibrate", "adaptive", "final_dark", "CaptureContext", "capture",
               "check_sample", "last_recorded", "footprint_of", "RESUME_CHECK_POINTS", "RESUME_CHECK_SIGMAS",
               "RESUME_DRIFT_ALLOWANCE")


def __getattr__(name: str) -> object:
    if name in _GENERATORS:
        return getattr(importlib.import_module("acquisition.plans.generators"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
