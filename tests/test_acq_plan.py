"""Pure unit tests: plan checks, ordering, time estimates, scenes, adaptive refinement, calibration math."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from acquisition import ConfigError, Plan, PlanError
from acquisition.calibration import Calibration, Reading, reference_rho
from acquisition.config import config_from_dict
from acquisition.plans.geometry import Geometry, _trapezoid_time
from acquisition.plans.ordering import order_points, path_time
from acquisition.plans.plan import load_scene as acq_load_scene
from acquisition.plans.refine import refine_points
from reconstruction.core.scene import Scene, load_scene
from tests.test_acq_support import REPO, make_raw


@pytest.fixture(scope="module")
def geom() -> Geometry:
    return Geometry.from_config(config_from_dict(make_raw(), "t.toml"))


def test_trapezoid_time():
    # v = 100 deg/s, a = 400 deg/s^2: ramp distance v^2/a = 25 deg
    assert _trapezoid_time(100.0, 100.0, 400.0) == pytest.approx(100 / 100 + 100 / 400)
    assert _trapezoid_time(16.0, 100.0, 400.0) == pytest.approx(2 * math.sqrt(16 / 400))
    assert _trapezoid_time(0.0, 100.0, 400.0) == 0.0
    assert _trapezoid_time(10.0, math.inf, math.inf) == 0.0


def test_dynamixel_speeds_from_profile(geom):
    v, a = geom.light_speed
    assert v == pytest.approx(200 * 0.229 * 360 / 60)        # 274.8 deg/s
    assert a == pytest.approx(50 * 214.577 * 360 / 3600)     # 1072.9 deg/s^2


def test_reasons(geom):
    assert geom.reason(30, 20) is None
    assert "light arm soft limits" in geom.reason(87, 0)
    assert "detector arm soft limits" in geom.reason(30, 89)
    assert geom.reason(30, -30).startswith("collision")
    # 30 and -24 are 6 deg apart nominally, but 5.98 deg at the quantised goals the servos would get
    assert geom.reason(30, -24).startswith("collision")
    g = Geometry(geom.light, geom.detector, 2.0, 4.0)
    assert g.reason(30, -27).startswith("blind spot")


def test_check_lists_every_unmeasurable_point(geom):
    plan = Plan.grid([30.0], -80, 80, 2)
    chk = plan.check(geom)
    assert len(chk.measurable) + len(chk.unmeasurable) == 81
    assert {(ti, to) for ti, to, _ in chk.unmeasurable} >= {(30.0, -30.0), (30.0, -28.0), (30.0, -32.0)}
    assert chk.unreachable == []
    plan.validate(geom)  # collision / blind spot points are listed, not errors
    with pytest.raises(PlanError, match="cannot be measured"):
        Plan.grid([30.0], -80, 80, 2, strict=True).validate(geom)
    with pytest.raises(PlanError, match=r"\(30, -89\)"):
        Plan.grid([30.0], -89, 80, 1).validate(geom)


def test_grid_includes_range_end_and_dedups():
    pts = Plan.grid([10.0], -10, 10, 3).requested_points()
    assert pts[0] == (10.0, -10.0) and pts[-1] == (10.0, 10.0) and len(pts) == 8
    assert len(Plan.from_points([(1, 2), (1, 2.0000000001), (1, 3)]).requested_points()) == 2


def test_optimized_order_is_a_permutation_and_faster(geom):
    plan = Plan.grid([20.0, 40.0, 60.0], -80, 80, 2)
    pts = plan.check(geom).measurable
    rng = np.random.default_rng(3)
    shuffled = [pts[i] for i in rng.permutation(len(pts))]
    ordered = order_points(shuffled, geom)
    assert sorted(ordered) == sorted(pts)
    t_opt, t_naive, t_shuffled = path_time(ordered, geom), path_time(pts, geom), path_time(shuffled, geom)
    assert t_opt < t_naive < t_shuffled
    est = plan.estimate(geom, 0.01)
    assert est["motion_s"] == pytest.approx(t_opt, rel=0.05) and est["naive_motion_s"] == pytest.approx(t_naive)


def test_order_does_not_depend_on_machine_speed(geom, monkeypatch):
    """The 2-opt improvement stops on a work budget, not a clock: a machine so loaded that every clock reading
    is a second later orders the points exactly as an idle one."""
    import time

    rng = np.random.default_rng(7)
    pts = [(float(a), float(b)) for a, b in zip(rng.uniform(0, 80, 300), rng.uniform(-80, 80, 300), strict=True)
           if abs(a + b) > 8]
    idle = order_points(pts, geom)
    clock = itertools.count()
    monkeypatch.setattr(time, "perf_counter", lambda: float(next(clock)))
    monkeypatch.setattr(time, "monotonic", lambda: float(next(clock)))
    assert order_points(pts, geom) == idle
    assert sorted(idle) == sorted(pts)
    unimproved = order_points(pts, geom, max_evaluations=0)  # the best of the initial tours
    assert path_time(idle, geom) < path_time(unimproved, geom)  # 2-opt did improve it


def test_order_small_sets_optimal(geom):
    pts = [(20.0, 10.0), (60.0, -10.0), (40.0, 70.0), (20.0, 50.0), (60.0, 30.0)]
    best = min(path_time(list(p), geom) for p in itertools.permutations(pts))
    assert path_time(order_points(pts, geom), geom) <= best * 1.05


def test_scene_restricts_plan(tmp_path):
    plan = Plan.grid([10.0, 20.0, 40.0, 60.0], -80, 80, 2)
    glossy = load_scene(REPO / "configs" / "scenes" / "glossy-product.toml")
    p = plan.restrict(glossy)
    tis = sorted({ti for ti, _ in p.requested_points()})
    tos = sorted({to for _, to in p.requested_points()})
    assert tis == [20.0, 40.0]  # theta_i in [15, 45]
    assert tos[0] == -75.0 and tos[-1] == 75.0 and tos[1] - tos[0] == 1.0  # |theta_o| <= 75 at 1 deg
    grazing = load_scene(REPO / "configs" / "scenes" / "grazing.toml")
    p = plan.restrict(grazing)
    pts = p.requested_points()
    assert {ti for ti, _ in pts} == {60.0} and all(40.0 <= abs(to) <= 80.0 for _, to in pts)
    assert len(pts) == 2 * 41  # both sides of the normal, 40..80 every degree (the plan stops at 80)
    matte = load_scene(REPO / "configs" / "scenes" / "matte-architecture.toml")
    p = plan.restrict(matte)
    assert sorted({ti for ti, _ in p.requested_points()}) == [10.0, 20.0, 40.0, 60.0]
    assert len(p.requested_points()) == 4 * 33
    with pytest.raises(PlanError, match="keeps none"):
        Plan.grid([70.0], -80, 80, 2).restrict(glossy)
    # acquisition reads scene files through reconstruction.core.scene; its errors are ConfigErrors there
    (tmp_path / "s.toml").write_text("[scene]\nname = 'x'\nangular_resolution_deg = 'fine'\n")
    with pytest.raises(ConfigError, match=r"s.toml: \[scene\].angular_resolution_deg: expected a positive number"):
        acq_load_scene(tmp_path / "s.toml")
    (tmp_path / "s.toml").write_text("[scene]\ntheta_o_deg = [10, 95]\n")
    with pytest.raises(ConfigError, match=r"\[scene\].theta_o_deg: expected \[min, max\]"):
        acq_load_scene(tmp_path / "s.toml")
    (tmp_path / "s.toml").write_text("[scene]\nresolution = 1\n")
    with pytest.raises(ConfigError, match=r"\[scene\].resolution: unknown key"):
        acq_load_scene(tmp_path / "s.toml")
    with pytest.raises(ConfigError, match="none.toml: no such scene file"):
        acq_load_scene(tmp_path / "none.toml")
    assert acq_load_scene(REPO / "configs" / "scenes" / "grazing.toml") == grazing


def test_scene_without_ranges_keeps_the_whole_hemisphere():
    # the capture's default range is the whole hemisphere (the fit's is 0-85 deg: reconstruction.methods.fit)
    p = Plan.grid([10.0, 88.0], -89.5, 89.5, 0.5).restrict(Scene(name="all"))
    pts = p.requested_points()
    assert {ti for ti, _ in pts} == {10.0, 88.0}
    assert min(to for _, to in pts) == -89.5 and max(to for _, to in pts) == 89.5


def test_scene_sets_adaptive_tolerance():
    from reconstruction.schema.bench import AdaptiveTable as AdaptiveConfig

    plan = Plan.grid([20.0], -80, 80, 2, adaptive=AdaptiveConfig(True, 8.0, 2.0, 0.1, 0.0, 0, 6))
    p = plan.restrict(load_scene(REPO / "configs" / "scenes" / "glossy-product.toml"))
    assert p.adaptive.tolerance == 0.03 and p.adaptive.min_step_deg == 1.0


def test_fingerprint_tracks_points_and_repeats():
    a = Plan.grid([30.0], -80, 80, 2)
    assert a.fingerprint() == Plan.grid([30.0], -80, 80, 2).fingerprint()
    assert a.fingerprint() != Plan.grid([30.0], -80, 80, 4).fingerprint()
    assert a.fingerprint() != Plan.grid([30.0], -80, 80, 2, repeats=8).fingerprint()


def _samples(f, xs, noise=0.0, ti=30.0):
    return {ti: [(x, f(x), noise) for x in xs]}


def test_refine_adds_points_at_a_peak_only(geom):
    xs = list(np.arange(-80.0, 81.0, 8.0))
    peak = lambda x: 0.05 + 2.0 * math.exp(-0.5 * ((x - 30.0) / 3.0) ** 2)  # noqa: E731
    new = refine_points(_samples(peak, xs), geom, 0.05, 1.0)
    assert new and all(10.0 <= to <= 50.0 for _, to in new)
    flat = refine_points(_samples(lambda x: 0.1 + 1e-4 * x, xs), geom, 0.05, 1.0)
    assert flat == []


def test_refine_ignores_noise_and_respects_min_step(geom):
    rng = np.random.default_rng(0)
    xs = list(np.arange(-80.0, 81.0, 8.0))
    noisy = {30.0: [(x, 0.1 + 0.003 * rng.standard_normal(), 0.003) for x in xs]}
    assert refine_points(noisy, geom, 0.05, 1.0) == []
    xs2 = [28.0, 29.0, 30.0, 31.0, 32.0]
    assert refine_points(_samples(lambda x: abs(x - 30.0), xs2), geom, 0.01, 1.0) == []


def test_refine_skips_unmeasurable_midpoints(geom):
    xs = [-40.0, -32.0, -24.0]  # midpoint -28 is in the collision zone of theta_i = 30
    new = refine_points(_samples(lambda x: 1.0 + (x + 32.0) ** 2, xs), geom, 0.01, 1.0)
    assert all(geom.reason(*p) is None for p in new)


# --- calibration math -----------------------------------------------------------------------------------------


def _reading(x, n=4, sd=0.0):
    x = np.atleast_1d(np.asarray(x, dtype=float))
    return Reading(x, np.full_like(x, sd), n)


@settings(max_examples=60, deadline=None)
@given(f=st.floats(0.001, 50.0), rho=st.floats(0.2, 1.0), to=st.floats(-85, 85), to_ref=st.floats(-60, 60),
       k=st.floats(1e2, 1e7), dark=st.floats(0, 1000))
def test_relative_calibration_recovers_f(f, rho, to, to_ref, k, dark):
    """With S = K f cos(theta_o) + dark for sample and reference, the relative formula gives f back."""
    s_ref = k * rho / math.pi * math.cos(math.radians(to_ref)) + dark
    s = k * f * math.cos(math.radians(to)) + dark
    cal = Calibration("relative", _reading(dark), _reading(s_ref), np.array([rho]), to_ref)
    got, sd = cal.brdf(_reading(s, n=4, sd=2.0), to)
    assert got[0] == pytest.approx(f, rel=1e-9)
    assert sd[0] == pytest.approx(1.0 * cal.scale(to)[0], rel=1e-12)  # std of the mean = 2 / sqrt(4)


def test_relative_formula_at_reference_geometry():
    cal = Calibration("relative", _reading(100.0), _reading(600.0), np.array([0.99]), 10.0)
    f, _ = cal.brdf(_reading(350.0), 10.0)  # f = (S - D) / (R - D) * rho / pi
    assert f[0] == pytest.approx(250.0 / 500.0 * 0.99 / math.pi)


def test_absolute_calibration():
    cal = Calibration("absolute", _reading(200.0), k_counts=1e3)
    f, _ = cal.brdf(_reading(200.0 + 1e3 * 0.3 * math.cos(math.radians(60))), 60.0)
    assert f[0] == pytest.approx(0.3)


def test_reference_without_signal_is_an_error():
    cal = Calibration("relative", _reading(100.0), _reading(99.0), np.array([0.99]), 10.0)
    with pytest.raises(ValueError, match="white reference"):
        cal.brdf(_reading(150.0), 0.0)


def test_reference_rho_spectrum():
    spec = ((400.0, 500.0, 700.0), (0.9, 0.95, 0.99))
    assert reference_rho(0.98, None, None).tolist() == [0.98]
    assert reference_rho(None, spec, [400.0, 450.0, 800.0]) == pytest.approx([0.9, 0.925, 0.99])
    assert reference_rho(None, spec, None) == pytest.approx([np.mean([0.9, 0.95, 0.99])])
