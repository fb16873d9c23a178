"""The end-to-end pipeline as a library function (a typed Job, no argparse), and the methods' option schemas."""

from __future__ import annotations

import json

import pytest

from reconstruction import methods, pipeline
from reconstruction.base import ReconstructionError
from reconstruction.formats import merl
from reconstruction.job import Job
from reconstruction.methods import Options
from tests.test_cli_reconstruct import BLUE_PLASTIC, slice_file


def test_a_job_runs_the_whole_pipeline_without_a_command_line(tmp_path):
    src = slice_file(tmp_path / "slice.csv", BLUE_PLASTIC)
    steps = []

    class Steps:
        def begin(self, label):
            pass

        def done(self, step):
            steps.append(step)

    job = Job(inputs=(str(src),), out=str(tmp_path / "m.binary"), method="bivariate",
                       report=str(tmp_path / "m.json"))
    rep = pipeline.run(job, progress=Steps())
    assert sorted(steps) == sorted(job.steps) == ["checks", "colour", "read", "reconstruct", "tabulate", "write"]
    assert rep["method"] == "bivariate" and (tmp_path / "m.binary").stat().st_size == merl.FILE_SIZE
    assert json.loads((tmp_path / "m.json").read_text())["method"] == "bivariate"
    with pytest.raises(ReconstructionError, match="--out .*expected a file name ending in .binary"):
        pipeline.run(Job(inputs=(str(src),), out=str(tmp_path / "m.bin")))


def test_every_method_declares_its_options_schema():
    schema = methods.options_schema()
    assert set(schema["properties"]) == set(methods.names())
    assert schema["$defs"]["RevolveOptions"]["properties"]["axis"]["enum"] == ["auto", "pca", "vertical"]
    rev = methods.get("revolve")
    assert rev.options_from(Options(fill="zero", revolve_axis="pca")) == methods.RevolveOptions(
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
    monkeypatch.setenv("GONIO_FORK", "0")  # the second thread's work (the forked child's is the next test's)
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
    rep = pipeline.run(Job(inputs=(str(src),), out=str(tmp_path / "m.binary"), method="auto"))
    assert rep["conservative"] is not None
    assert {"cv microfacet", "cv revolve", "cv bivariate", "posterior"} <= set(events)
    assert events.index("posterior") > max(events.index(f"cv {m}") for m in ("microfacet", "revolve", "bivariate"))


def _pid_and(x):
    import os

    return os.getpid(), x


def _fails(x):
    raise ValueError(f"bad {x}")


def test_forked_child_runs_tasks_beside_this_process_and_falls_back_here():
    """Forked: a task runs in the child (another pid) and its result comes back in order; a task that fails there
    runs again here and raises here; a task that does not pickle runs here; with the child gone, or without fork,
    the tasks run here."""
    import os

    from reconstruction import executor

    with executor.Forked() as child:
        assert child.alive and executor.forked() is child
        a, b = child.submit(_pid_and, 1), child.submit(_pid_and, 2)
        assert b() == (b()[0], 2) and a()[1] == 1 and a()[0] != os.getpid() and a()[0] == b()[0]
        bad = child.submit(_fails, 3)
        with pytest.raises(ValueError, match="bad 3"):
            bad()
        local = child.submit(lambda: os.getpid())  # a lambda does not pickle: run here
        assert local() == os.getpid()
        os.kill(child._pid, 9)
        late = child.submit(_pid_and, 4)
        assert late() == (os.getpid(), 4)
    assert executor.forked() is None
    with executor.Forked(enabled=False) as none:
        assert not none.alive and executor.forked() is None
        assert none.submit(_pid_and, 5)() == (os.getpid(), 5)


def test_auto_cross_validates_in_the_forked_child_with_the_same_result(tmp_path, monkeypatch):
    """In a run on two cores, auto's microfacet, revolve and bivariate are cross-validated in the run's forked
    child (their fits hold the GIL), and with the HTML page built there on all samples too; the scores, the
    choice, the table and the page's figures are those of the same run without the child (GONIO_FORK=0: in a
    second thread, and the page's methods built here)."""
    import dataclasses
    import re

    from reconstruction import executor
    from reconstruction.methods import auto

    monkeypatch.setattr(executor.os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    here: list[str] = []  # cross-validations run in this process (the child's calls stay in the child)
    real = auto.cross_validate

    def cv(s, name, *args, **kw):
        here.append(name)
        return real(s, name, *args, **kw)

    monkeypatch.setattr(auto, "cross_validate", cv)
    mf = auto.REGISTRY["microfacet"]
    real_build = mf.build

    def build(s, *args, **kw):
        here.append("microfacet built")
        return real_build(s, *args, **kw)

    monkeypatch.setitem(auto.REGISTRY, "microfacet", dataclasses.replace(mf, build=build))
    src = slice_file(tmp_path / "slice.csv", BLUE_PLASTIC, incidences=(20.0, 50.0), step=4.0)
    reps, pages = {}, {}
    for fork in ("1", "0"):
        monkeypatch.setenv("GONIO_FORK", fork)
        here.clear()
        out, page = tmp_path / f"m{fork}.binary", tmp_path / f"m{fork}.html"
        reps[fork] = pipeline.run(Job(inputs=(str(src),), out=str(out), method="auto", html=str(page)))
        assert ("microfacet" in here) == ("microfacet built" in here) == (fork == "0") and "fit" in here
        pages[fork] = re.findall(r"data:image/png;base64,[^\"']+", page.read_text())
    assert len(pages["1"]) == 12 and pages["1"] == pages["0"]
    def scores(rep):
        return [{k: v for k, v in x.items() if k != "seconds"} for x in rep["cross_validation"]["scores"]]

    assert scores(reps["1"]) == scores(reps["0"]) and len(scores(reps["1"])) == 4
    assert (tmp_path / "m1.binary").read_bytes() == (tmp_path / "m0.binary").read_bytes()


def test_auto_with_the_html_page_ends_with_both_children(tmp_path):
    """auto with --html forks two children, the page's drawer and auto's cross-validation: each must hold only
    its own pipes, or the drawer never sees the end of its input and the run waits forever (a separate process
    with a timeout, so that a regression fails instead of hanging the suite)."""
    import subprocess
    import sys

    src = slice_file(tmp_path / "slice.csv", BLUE_PLASTIC, incidences=(20.0, 50.0), step=4.0)
    env = {k: v for k, v in __import__("os").environ.items() if k not in ("GONIO_FORK", "GONIO_HTML_FORK")}
    done = subprocess.run([sys.executable, "-m", "reconstruction.cli", str(src), "--method", "auto", "--out",
                           str(tmp_path / "m.binary"), "--html", str(tmp_path / "m.html"), "--quiet"],
                          capture_output=True, text=True, timeout=300, env=env)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "m.html").stat().st_size > 10_000


def _wait_for(path, x):
    """A task that runs until ``path`` exists (at most 30 s)."""
    import os
    import time

    for _ in range(3000):
        if os.path.exists(path):
            return x
        time.sleep(0.01)
    return None


def test_a_large_task_is_sent_while_the_child_is_busy(tmp_path):
    """The forked child reads tasks as they come: sending one larger than a pipe's buffer while it runs another
    does not wait for that one to end (the parent's main thread sends auto's cross-validation while the child is
    still importing). The first task here ends only once the second is sent."""
    import threading

    from reconstruction import executor

    flag = tmp_path / "sent"
    with executor.Forked() as child:
        first = child.submit(_wait_for, str(flag), 1)
        sent = threading.Event()

        def send():
            child.submit(_pid_and, b"x" * (1 << 20))
            sent.set()

        t = threading.Thread(target=send, daemon=True)
        t.start()
        ok = sent.wait(20.0)  # a child that read only between tasks would hold it until the first one ends
        flag.touch()
        assert ok and first() == 1
        t.join(20.0)


def test_autos_bound_table_is_made_beside_the_run_once_with_the_same_result(tmp_path, monkeypatch):
    """The analytic family's upper bound table is computed by the helper thread with its posterior (not on the
    main thread after the checks), once per run, and the bound it gives is the one computed in line."""
    import threading

    from reconstruction import executor
    from reconstruction.assess import guard

    src = slice_file(tmp_path / "slice.csv", BLUE_PLASTIC)
    monkeypatch.setenv("GONIO_FORK", "0")
    made = []
    real = guard.upper_bound_table

    def recorded(ref, k=guard.GUARD_SIGMAS):
        made.append(threading.current_thread() is threading.main_thread())
        return real(ref, k)

    monkeypatch.setattr(guard, "upper_bound_table", recorded)
    outs = {}
    for cores in ({0, 1}, {0}):  # a helper thread, then none (the work runs when asked for, on the main thread)
        monkeypatch.setattr(executor.os, "sched_getaffinity", lambda pid, c=cores: c, raising=False)
        made.clear()
        out = tmp_path / f"m{len(cores)}.binary"
        rep = pipeline.run(Job(inputs=(str(src),), out=str(out), method="auto"))
        assert made == [len(cores) == 1], made
        outs[len(cores)] = (out.read_bytes(), rep["conservative"])
    assert outs[2] == outs[1]


def test_import_methods_imports_the_registered_methods_modules_ahead():
    """What auto imports ahead (while its child works) comes from the registry: every always-tried method's
    declared modules, scipy's optimize among them; a method that needs an option (prior) is not imported."""
    import subprocess
    import sys

    code = ("import sys; from reconstruction.methods import REGISTRY; from reconstruction.methods.auto import "
            "import_methods; before = set(sys.modules); import_methods(); "
            "want = [mod for m in REGISTRY.values() if m.available is None for mod in m.modules]; "
            "print(len(want), all(w in sys.modules for w in want), 'scipy.optimize' in set(sys.modules) - before, "
            "'reconstruction.methods.prior' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    n, all_in, scipy_new, prior_in = r.stdout.split()
    assert int(n) >= 4 and all_in == "True" and scipy_new == "True" and prior_in == "False", r.stdout
