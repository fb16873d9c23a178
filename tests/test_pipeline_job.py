"""The end-to-end pipeline as a library function (a typed Job, no argparse), and the methods' option schemas."""

from __future__ import annotations

import json

import pytest

from reconstruction import methods, pipeline
from reconstruction.base import ReconstructionError
from reconstruction.formats import merl
from tests.test_cli_reconstruct import BLUE_PLASTIC, slice_file


def test_a_job_runs_the_whole_pipeline_without_a_command_line(tmp_path):
    src = slice_file(tmp_path / "slice.csv", BLUE_PLASTIC)
    steps = []

    class Steps:
        def begin(self, label):
            pass

        def done(self, step):
            steps.append(step)

    job = pipeline.Job(inputs=(str(src),), out=str(tmp_path / "m.binary"), method="bivariate",
                       report=str(tmp_path / "m.json"))
    rep = pipeline.run(job, progress=Steps())
    assert sorted(steps) == sorted(job.steps) == ["checks", "colour", "read", "reconstruct", "tabulate", "write"]
    assert rep["method"] == "bivariate" and (tmp_path / "m.binary").stat().st_size == merl.FILE_SIZE
    assert json.loads((tmp_path / "m.json").read_text())["method"] == "bivariate"
    with pytest.raises(ReconstructionError, match="--out .*expected a file name ending in .binary"):
        pipeline.run(pipeline.Job(inputs=(str(src),), out=str(tmp_path / "m.bin")))


def test_every_method_declares_its_options_schema():
    schema = methods.options_schema()
    assert set(schema["properties"]) == set(methods.names())
    assert schema["$defs"]["RevolveOptions"]["properties"]["axis"]["enum"] == ["auto", "pca", "vertical"]
    rev = methods.get("revolve")
    assert rev.options_from(pipeline.Options(fill="zero", revolve_axis="pca")) == methods.RevolveOptions(
        axis="pca", fill="zero")
    with pytest.raises(ReconstructionError, match=r"method fit: options: .*\$\.lobes\[0\]"):
        methods.get("fit").parse_options({"lobes": ["gx"]})


def test_spare_core_holds_work_until_released():
    """SpareCore.later(fn) waits for the release (release_spare_core from a copy of the context, as a background
    thread's work sees it) or for the end of the block; hold=False waits for nothing."""
    import contextvars
    import threading

    from reconstruction.executor import SpareCore, release_spare_core

    ran = threading.Event()
    with SpareCore() as spare:
        t = threading.Thread(target=spare.later(ran.set))
        t.start()
        assert not ran.wait(0.2)  # held
        contextvars.copy_context().run(release_spare_core)
        t.join(5.0)
        assert ran.is_set()
    ran.clear()
    with SpareCore() as spare:
        t = threading.Thread(target=spare.later(ran.set))
        t.start()
        assert not ran.wait(0.1)
    t.join(5.0)  # the block's end released it
    assert ran.is_set()
    assert SpareCore(hold=False).gate.is_set()
    release_spare_core()  # outside any block: nothing to release, no error


def test_auto_starts_the_bound_posterior_after_its_background_cross_validation(tmp_path, monkeypatch):
    """With two cores, auto's background thread cross-validates microfacet, revolve and bivariate while fit runs;
    the conservative bound's posterior (in the pipeline's helper thread) starts only once that is done, so no
    third busy thread slows fit on two cores."""
    from reconstruction import executor
    from reconstruction.assess import uncertainty
    from reconstruction.methods import auto

    monkeypatch.setattr(executor.os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    events: list[str] = []  # in the order they happened
    real_cv, real_post = auto.cross_validate, uncertainty.reference_posterior

    def cv(s, name, *args, **kw):
        out = real_cv(s, name, *args, **kw)
        events.append(f"cv {name}")  # a method's folds are done
        return out

    def post(*args, **kw):
        events.append("posterior")  # the posterior starts
        return real_post(*args, **kw)

    monkeypatch.setattr(auto, "cross_validate", cv)
    monkeypatch.setattr(uncertainty, "reference_posterior", post)
    src = slice_file(tmp_path / "slice.csv", BLUE_PLASTIC, incidences=(20.0, 50.0), step=4.0)
    rep = pipeline.run(pipeline.Job(inputs=(str(src),), out=str(tmp_path / "m.binary"), method="auto"))
    assert rep["conservative"] is not None
    assert {"cv microfacet", "cv revolve", "cv bivariate", "posterior"} <= set(events)
    assert events.index("posterior") > max(events.index(f"cv {m}") for m in ("microfacet", "revolve", "bivariate"))
