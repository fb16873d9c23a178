"""gonio-reconstruct --batch: a folder of slices reconstructed separately through the shared executor."""

import json

import numpy as np
import pytest

from reconstruction import cli
from reconstruction.core import merltable
from reconstruction.core.metrics import relative_rmse_cos
from reconstruction.formats import merl
from tests.test_cli_reconstruct import BLUE_PLASTIC, slice_file


@pytest.mark.slow
def test_batch_reconstructs_every_slice_and_reports_failures(tmp_path, capsys):
    src = tmp_path / "captures"
    (src / "run1").mkdir(parents=True)
    slice_file(src / "run1" / "slice.csv", BLUE_PLASTIC)  # a capture folder
    slice_file(src / "loose.csv", BLUE_PLASTIC, incidences=(20.0, 50.0))
    (src / "broken.csv").write_text("theta,value\n1,2\n")  # a generic table without --quantity
    out = tmp_path / "materials"
    assert cli.main(["--batch", str(src), "--out-dir", str(out), "--workers", "2", "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "broken: error:" in err and "2 of 3 reconstructed" in err
    truth = merltable.tabulate(BLUE_PLASTIC.eval)
    for name in ("run1", "loose"):
        assert relative_rmse_cos(merl.read(out / f"{name}.binary"), truth) < 0.02
        assert json.loads((out / f"{name}.json").read_text())["method"] == "fit"
    assert not (out / "broken.binary").exists()


def test_batch_usage_errors(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["--batch", str(tmp_path), "--out", "x.binary"])
    assert e.value.code == 2
    assert cli.main(["--batch", str(tmp_path / "nowhere")]) == 2
    assert "not a folder" in capsys.readouterr().err
    assert cli.main(["--batch", str(tmp_path)]) == 2
    assert "no *.csv" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main([])  # neither inputs nor --batch


def test_batch_files_names(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "slice.csv").write_text("")
    (tmp_path / "b.csv").write_text("")
    (tmp_path / "c.txt").write_text("")
    assert [n for n, _ in cli.batch_files(tmp_path)] == ["a", "b"]
    assert np.all([p.exists() for _, p in cli.batch_files(tmp_path)])


def test_unreachable_scheduler_and_bad_worker_counts_are_clear_errors(tmp_path, capsys):
    from reconstruction.executor import make_executor

    with pytest.raises(RuntimeError, match=r"--scheduler tcp://127.0.0.1:9: cannot connect"):
        with make_executor("tcp://127.0.0.1:9", connect_timeout_s=1.0):
            pass
    with pytest.raises(RuntimeError, match="--workers 0"):
        with make_executor(workers=0):
            pass
    with pytest.raises(SystemExit) as e:
        cli.main(["--batch", str(tmp_path), "--workers", "-1"])
    assert e.value.code == 2 and "positive integer" in capsys.readouterr().err
