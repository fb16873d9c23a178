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
