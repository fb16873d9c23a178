"""Captures as plans: a procedure of one's own (examples/reference_every_n.py), the dry run behind --check, the
reasons a point cannot be measured."""

from __future__ import annotations

import importlib.util

import pytest

from acquisition import Bench, Plan, PlanError, Reason
from acquisition.plans.messages import Move, Settle
from acquisition.run.dryrun import estimate
from acquisition.run.engine import Engine
from tests.test_acq_support import REPO, make_raw, write_config


def _example():
    spec = importlib.util.spec_from_file_location("reference_every_n", REPO / "examples" / "reference_every_n.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_re_reading_the_white_reference_every_n_points_is_a_plan_of_a_few_lines(tmp_path):
    bench = Bench.from_config(write_config(tmp_path / "c.toml", make_raw()))
    plan = Plan.grid([30.0], -20.0, 20.0, 10.0, repeats=2)
    result = bench.capture(plan, out=tmp_path / "run", progress=False, points_plan=_example().reference_every(2))
    assert result.ok and result.samples_total == 5, result.message
    log = (tmp_path / "run" / "capture.log").read_text()
    assert log.count("white reference read again") == 2  # before the 3rd and the 5th point
    assert log.count("measuring the white reference") == 3  # the calibration's and the two re-readings


def test_the_dry_run_checks_limits_and_models_time(tmp_path):
    bench = Bench.from_config(write_config(tmp_path / "c.toml", make_raw()))
    g = bench.geometry
    plan = Plan.grid([30.0], -60.0, 60.0, 5.0, repeats=3)
    pts = plan.check(g).measurable
    est = estimate(plan, g, 0.01, pts)
    assert est["total_s"] == pytest.approx(est["motion_s"] + len(pts) * (g.settle_s + 3 * 0.01))
    assert est["motion_s"] <= est["naive_motion_s"] + 1e-9
    with pytest.raises(PlanError, match=r"refusing to move to \(30, 89\): theta_o 89 outside"):
        estimate(plan, g, 0.01, [(30.0, 10.0), (30.0, 89.0)])
    # the engine throws a device's failure into the plan, whose own clean-up still runs
    from acquisition.run.dryrun import DryRunBench

    seen = []

    def plan_gen():
        try:
            yield Move(30.0, 200.0, checkpoint=False)
        finally:
            seen.append("clean-up")
            yield Settle()

    dry = DryRunBench(g, 0.01)
    dry.set = lambda ti, to: (_ for _ in ()).throw(PlanError("beyond the limits"))
    with pytest.raises(PlanError, match="beyond the limits"):
        Engine(dry.devices(), settle_s=0.1, retries=0, account=False).run(plan_gen())
    assert seen == ["clean-up"] and dry.settle_s == pytest.approx(0.1)


def test_unmeasurable_points_carry_their_reason(tmp_path):
    bench = Bench.from_config(write_config(tmp_path / "c.toml", make_raw()))
    chk = Plan.grid([30.0], -40.0, 40.0, 2.0).check(bench.geometry)
    reasons = {why.reason for _, _, why in chk.unmeasurable}
    assert reasons and reasons <= {Reason.COLLISION, Reason.BLIND_SPOT}
    assert not chk.unreachable and all(isinstance(why, str) for _, _, why in chk.unmeasurable)
