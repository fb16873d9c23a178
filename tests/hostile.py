"""The hostile-input campaign of issue 11, shared by the tests and ``scripts/hostile_campaign.py``.

Three corpora, each a list of :class:`Case` run as a subprocess (the programs as a user runs them; the test suite
forks most of them from warm interpreters, :func:`run_all`):

* :func:`reconstruct_cases`: input tables for ``gonio-reconstruct`` (truncated, wrong header, non-numeric,
  NaN/inf, out-of-range angles, duplicates, huge/negative values, BOM, CRLF/CR, other separators, empty, binary
  garbage, directories, unreadable files, a pipe, a MERL file as a CSV, long fields and names, non-UTF-8) and
  hostile outputs (folders, read-only folders, a full disk);
* :func:`capture_check_cases`: the same kinds of hostile files as bench configs and scene files for
  ``gonio-capture --check``;
* :func:`config_mutations`: systematic mutations of a shipped bench config (wrong types, signs, NaN/inf, huge and
  tiny numbers, missing and unknown keys) for ``gonio-capture --check``, then a capture of the ones it accepts.

A case is handled cleanly when it exits 0 or 2 (1 only for an I/O fault; 3 when ``gonio-reconstruct`` refuses an
implausible table), prints no traceback, and leaves no
output half-written under its real name (every output is absent or complete, no temporary file is left).
"""

from __future__ import annotations

import copy
import math
import os
import queue
import re
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from tests.forkserver import ForkServer

REPO = Path(__file__).resolve().parents[1]
CONFIGS = {name: REPO / "configs" / f"{name}.toml" for name in ("simulated", "dynamixel-bench", "serial-bench")}

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


@dataclass
class Case:
    """One hostile run: ``program`` ("reconstruct" or "capture") with ``argv``; ``outputs`` must be absent or
    complete afterwards; ``io_fault``: exit status 1 is the right answer (a full disk); ``expect``: text the
    message must contain (names the file, line or key); ``ok``: the run must succeed (exit 0)."""

    name: str
    program: str
    argv: list[str]
    outputs: list[Path] = field(default_factory=list)
    io_fault: bool = False
    expect: list[str] = field(default_factory=list)
    ok: bool | None = None
    unprivileged: bool = False
    file_size_limit: int | None = None
    says: list[str] = field(default_factory=list)  # text stderr must contain whatever the exit status
    never: list[str] = field(default_factory=list)  # text stderr must not contain
    unchanged: list[Path] = field(default_factory=list)  # files the run must leave byte for byte as they were


@dataclass
class Outcome:
    case: Case
    code: int
    stderr: str
    problems: list[str]

    @property
    def traceback(self) -> bool:
        return "Traceback" in self.stderr

    @property
    def clean(self) -> bool:
        return not self.problems

    @property
    def half_written(self) -> bool:
        return any(p.startswith("half-written") or p.startswith("temporary") for p in self.problems)

    @property
    def lost(self) -> bool:
        """Data lost: an output half-written, or a file the run had to leave alone changed."""
        return self.half_written or any(p.startswith("changed") for p in self.problems)


# --- running -----------------------------------------------------------------------------------------------------


def _preexec(case: Case) -> Callable[[], None] | None:
    steps: list[Callable[[], None]] = []
    if case.unprivileged and os.geteuid() == 0:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)

        def drop() -> None:  # root without the capabilities that bypass permission bits
            for cap in (1, 2, 3):
                libc.prctl(24, cap, 0, 0, 0)

        steps.append(drop)
    if case.file_size_limit is not None:
        limit = case.file_size_limit

        def fsize() -> None:  # a full disk: writes beyond the limit fail (EFBIG)
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
            resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

        steps.append(fsize)
    if not steps:
        return None

    def run_all() -> None:
        for s in steps:
            s()

    return run_all


def _complete(path: Path) -> str | None:
    """None if ``path`` is absent or a complete output of its kind, else what is wrong with it."""
    if not path.exists():
        return None
    if path.is_dir():
        return None  # an output named after an existing folder: the case itself made it
    data = path.read_bytes()
    suffix = path.suffix.lower()
    if suffix == ".binary":
        from reconstruction.formats import merl

        if len(data) != merl.FILE_SIZE:
            return f"half-written table {path} ({len(data)} bytes)"
    elif suffix == ".json":
        import json

        try:
            json.loads(data)
        except ValueError:
            return f"half-written report {path}"
    elif suffix == ".png":
        if not (data.startswith(b"\x89PNG\r\n\x1a\n") and data.endswith(b"IEND\xaeB`\x82")):
            return f"half-written PNG {path}"
    elif suffix == ".exr":
        import OpenEXR

        try:
            with OpenEXR.File(str(path)) as f:
                f.channels()["RGB"].pixels.sum()
        except Exception:  # noqa: BLE001 - any failure to read it back
            return f"half-written EXR {path}"
    return None


def run_case(case: Case, timeout: float = 120.0, server: ForkServer | None = None) -> Outcome:
    """``case`` as ``python -m MODULE ARGV...``: a new interpreter, or (``server``) a child forked from a warm one
    (tests/forkserver.py: the same process boundary, exit status and stderr, without the interpreter's start)."""
    module = {"reconstruct": "reconstruction.cli", "capture": "acquisition.cli"}[case.program]
    kept = {p: p.read_bytes() if p.exists() else None for p in case.unchanged}
    if server is not None:
        if case.unprivileged:
            raise ValueError(f"{case.name}: dropping privileges needs a new interpreter (no fork server)")
        f = server.run(module, case.argv, timeout=timeout, file_size_limit=case.file_size_limit)
        code, err = (-1, f"timed out after {timeout:g} s: {f.stderr[-500:]!r}") if f.timed_out else (f.returncode,
                                                                                                      f.stderr)
    else:
        try:
            r = subprocess.run([sys.executable, "-m", module, *case.argv], cwd=REPO, capture_output=True,
                               text=True, timeout=timeout, stdin=subprocess.DEVNULL, preexec_fn=_preexec(case))
            code, err = r.returncode, r.stderr
        except subprocess.TimeoutExpired as e:
            code, err = -1, f"timed out after {timeout:g} s: {(e.stderr or b'')[-500:]!r}"
    problems = []
    allowed = {0, 2} | ({1} if case.io_fault else set()) | ({3} if case.program == "reconstruct" else set())
    if case.ok is True:
        allowed = {0}
    elif case.ok is False:
        allowed -= {0}
    if code not in allowed:
        problems.append(f"exit status {code} (expected {sorted(allowed)})")
    if "Traceback" in err:
        problems.append("a traceback")
    if code in (1, 2, 3) and code in allowed:
        lines = [ln for ln in err.splitlines() if ln.strip()]
        if len(lines) != 1:
            problems.append(f"{len(lines)} lines instead of one")
        for text in case.expect:
            if text not in err:
                problems.append(f"message lacks {text!r}")
    problems += [f"message lacks {t!r}" for t in case.says if t not in err]
    problems += [f"message has {t!r}" for t in case.never if t in err]
    problems += [f"changed {p}" for p, data in kept.items() if (p.read_bytes() if p.exists() else None) != data]
    for out in case.outputs:
        what = _complete(out)
        if what:
            problems.append(what)
        if out.parent.is_dir():
            try:
                tmp = [p.name for p in out.parent.iterdir() if p.name.startswith(".") and ".tmp" in p.name]
            except OSError:
                tmp = []
            if tmp:
                problems.append(f"temporary file(s) left: {tmp}")
    return Outcome(case, code, err, problems)


#: what the fork servers of :func:`run_all` import before forking: what the campaign's runs import
PRELOAD = ("reconstruction.cli", "acquisition.cli", "reconstruction.formats.brdffile", "reconstruction.formats.exports",
           "reconstruction.methods.bivariate", "reconstruction.report.summary", "reconstruction.report.preview",
           "acquisition.run.engine", "acquisition.run.dryrun")


def run_all(cases: list[Case], workers: int | None = None, real_every: int = 1) -> list[Outcome]:
    """Run ``cases``, ``workers`` at a time (default: one more than the CPUs, as the children also wait on I/O).

    ``real_every`` 1: every case in a new interpreter (``python -m``, as a user runs it). N > 1: every N-th case
    (the first included), every I/O-fault case and every unprivileged case in a new interpreter, the others as
    children forked from warm interpreters (tests/forkserver.py, one per worker), which skips the ~0.4 s of CPU an
    interpreter's start and imports cost per run; the outcomes are judged alike."""
    workers = workers or (os.cpu_count() or 1) + 1
    if real_every <= 1:
        with ThreadPoolExecutor(workers) as ex:
            return list(ex.map(run_case, cases))
    servers: queue.SimpleQueue[ForkServer] = queue.SimpleQueue()
    made: list[ForkServer] = []

    def one(k: int) -> Outcome:
        case = cases[k]
        if k % real_every == 0 or case.io_fault or case.unprivileged:
            return run_case(case)
        try:
            server = servers.get_nowait()
        except queue.Empty:
            server = ForkServer(PRELOAD)
            made.append(server)
        try:
            return run_case(case, server=server)
        finally:
            servers.put(server)

    try:
        with ThreadPoolExecutor(workers) as ex:
            return list(ex.map(one, range(len(cases))))
    finally:
        for server in made:
            server.close()


# --- the reconstruction corpus -----------------------------------------------------------------------------------


def _good_slice(path: Path) -> Path:
    from reconstruction.core.models import Material
    from reconstruction.core.slicedata import Slice
    from reconstruction.formats.slicefile import write_slice
    from reconstruction.synthetic import synthetic_slice

    mat = Material.from_dict({"name": "grey", "lobes": [{"type": "lambert", "albedo": 0.5},
                                                        {"type": "ggx", "alpha": 0.3, "specular": 0.2}]})
    s = synthetic_slice(mat, (30.0,), step_deg=10.0)
    n = len(s)
    write_slice(path, Slice(s.theta_i_deg, s.theta_o_deg, s.values, s.channels, 0.01 * s.values + 1e-6,
                            np.full(n, 4), 1.7e9 + np.arange(n), meta={"material": "grey"}))
    return path


def _edit_cell(text: str, row: int, col: int, value: str) -> str:
    lines = text.split("\n")
    cells = lines[row].split(",")
    cells[col] = value
    lines[row] = ",".join(cells)
    return "\n".join(lines)


def reconstruct_cases(work: Path) -> list[Case]:
    """The hostile inputs and outputs for ``gonio-reconstruct``, written into ``work``."""
    work.mkdir(parents=True, exist_ok=True)
    good = _good_slice(work / "good-slice.csv")
    st = good.read_text()
    generic = "theta_i,theta_o,value,value_std\n" + "\n".join(
        f"30,{to},{0.1 + 0.2 * math.exp(-((to - 30) / 15) ** 2):.6f},0.001" for to in range(-80, 81, 10)) + "\n"
    files: dict[str, tuple[bytes | None, list[str], bool | None, list[str]]] = {}

    def add(name: str, data: bytes | str | None, extra: list[str] | None = None, ok: bool | None = None,
            expect: list[str] | None = None) -> None:
        files[name] = (data.encode() if isinstance(data, str) else data, extra or [], ok, expect or [])

    q = ["--quantity", "brdf"]
    add("good-slice.csv", st, ok=True)
    add("good-generic.csv", generic, q, ok=True)
    # truncated
    for cut in (5, st.index("\ntheta_i") + 8, len(st) - 7):
        add(f"truncated-{cut}.csv", st[:cut])
    add("truncated-generic.csv", generic[: len(generic) // 2], q)
    # wrong header / metadata
    add("magic-typo.csv", st.replace("# gonio-brdf slice", "# gonio-brdf slise"))
    add("meta-not-json.csv", st.replace('# meta: {"', '# meta: {oops"', 1), expect=[":2: metadata is not valid"])
    add("meta-array.csv", st.replace("# meta: {", "# meta: [{", 1))
    add("meta-deep.csv", st.replace("# meta: {", "# meta: {\"x\": " + "[" * 100000 + "]" * 100000 + ", ", 1))
    add("format-version-2.csv", st.replace('"format_version": 1', '"format_version": 2'), ok=False)
    add("format-version-true.csv", st.replace('"format_version": 1', '"format_version": true'), ok=False,
        expect=["unsupported format_version True"])
    add("format-version-string.csv", st.replace('"format_version": 1', '"format_version": "1"'), ok=False)
    add("quantity-missing.csv", re.sub(r'"quantity": "brdf"(, )?', "", st), ok=False)
    add("quantity-list.csv", st.replace('"quantity": "brdf"', '"quantity": ["brdf"]'), ok=False)
    add("column-missing.csv", st.replace(",unix_time_s\n", "\n", 1), ok=False)
    add("column-twice.csv", st.replace("value_std,", "value_std,value_std,", 1), ok=False)
    add("column-unknown.csv", st.replace("theta_i_deg,", "theta_i_deg,temperature,", 1), ok=False)
    add("generic-no-angles.csv", generic.replace("theta_i,theta_o", "a,b"), q, ok=False)
    add("generic-dup-name.csv", generic.replace("value_std", "value"), q, ok=False)
    # non-numeric
    add("cell-text.csv", _edit_cell(st, 4, 2, "abc"), ok=False, expect=[":5, column value: expected a number"])
    add("cell-empty.csv", _edit_cell(st, 5, 3, ""), ok=False)
    add("generic-decimal-comma.csv", generic.replace(",", ";").replace(".", ","), q, ok=False)
    # NaN / inf
    for v in ("nan", "-inf"):
        add(f"value-{v}.csv", _edit_cell(st, 6, 2, v), ok=False)
    add("generic-inf-angle.csv", generic.replace("30,-80", "30,inf", 1), q, ok=False)
    # angles out of range
    for v in ("90", "-95", "1e10"):
        add(f"angle-{v}.csv", _edit_cell(st, 4, 1, v), ok=False)
    # duplicates, order
    lines = st.split("\n")
    add("duplicate-row.csv", "\n".join(lines[:5] + [lines[4]] + lines[5:]), ok=False, expect=["duplicate sample"])
    g = generic.split("\n")
    add("generic-duplicate.csv", "\n".join(g[:3] + [g[2]] + g[3:]), q, ok=False)
    add("generic-unsorted.csv", "\n".join([g[0], g[3], g[1], g[2]] + g[4:]), q, ok=True)  # any order (issue 41)
    # huge / negative values
    add("value-1e300.csv", _edit_cell(st, 4, 2, "1e300"), ok=False, expect=["beyond the physical bound 1e+08"])
    add("value--1e300.csv", _edit_cell(st, 4, 2, "-1e300"), ok=False)
    add("std-negative.csv", _edit_cell(st, 4, 3, "-0.5"), ok=False,
        expect=[":5, column value_std: a standard deviation must be >= 0"])
    add("std-1e300.csv", _edit_cell(st, 4, 3, "1e300"), ok=False)
    add("repeats-0.csv", _edit_cell(st, 4, 4, "0"), ok=False)
    add("repeats-1e300.csv", _edit_cell(st, 4, 4, "1e300"), ok=False)
    add("repeats-fraction.csv", _edit_cell(st, 4, 4, "1.5"), ok=False)
    add("all-negative.csv", generic.replace(",0.", ",-0."), q, ok=False)
    # BOM, line endings, separators
    add("bom-slice.csv", "\ufeff" + st, ok=True)
    add("crlf-slice.csv", st.replace("\n", "\r\n"), ok=True)
    add("cr-slice.csv", st.replace("\n", "\r"), ok=True)
    add("bom-crlf-generic.csv", "\ufeff" + generic.replace("\n", "\r\n"), q, ok=True)
    add("semicolon-generic.csv", generic.replace(",", ";"), q, ok=True)
    add("tab-generic.csv", generic.replace(",", "\t"), q, ok=True)
    add("semicolon-slice.csv", st.replace(",", ";"), ok=False)
    # empty
    add("empty.csv", "", ok=False)
    add("newline.csv", "\n", ok=False)
    add("header-only.csv", "theta_i,theta_o,value\n", q, ok=False)
    add("comments-only.csv", "# nothing\n# here\n", q, ok=False)
    add("slice-header-only.csv", "\n".join(st.split("\n")[:3]) + "\n", ok=False)
    # binary garbage, other files
    rng = np.random.default_rng(11)
    add("garbage.csv", rng.bytes(5000), q, ok=False)
    add("garbage-after-magic.csv", b"# gonio-brdf slice\n" + rng.bytes(5000), ok=False)
    add("nul-bytes.csv", generic.replace("0.001", "0.0\x0001"), q, ok=False)
    add("utf16.csv", generic.encode("utf-16"), q, ok=False)
    add("latin1.csv", generic.replace("value_std", "valeur_\xe9cart").encode("latin-1"), q, ok=False,
        expect=["not a UTF-8 text file"])
    # long fields and names
    add("long-number.csv", generic.replace("0.001\n", "0." + "1" * 200_000 + "\n", 1), q)  # a valid number
    add("long-field.csv", generic.replace("0.001\n", "1" * 200_000 + "x\n", 1), q, ok=False,
        expect=["field larger than field limit"])
    add("long-name.csv", generic.replace("value_std", "v" * 200_000), q, ok=False)
    add("long-name-100k.csv", generic.replace("value_std", "v" * 100_000), q, ok=False)
    add("long-cell-slice.csv", _edit_cell(st, 4, 2, "9" * 150_000 + "x"), ok=False)
    add("many-columns.csv", "theta_i,theta_o," + ",".join(f"{400 + k}nm" for k in range(20000)) + "\n"
        + "30,0," + ",".join("0.1" for _ in range(20000)) + "\n", q, ok=False)
    # a MERL table as a CSV
    from reconstruction.core import merltable
    from reconstruction.formats import merl

    merl.write(work / "merl-as.csv", np.full(merltable.SHAPE, 0.1))
    files["merl-as.csv"] = (None, q, False, [])

    cases: list[Case] = []
    for name, (data, extra, ok, expect) in files.items():
        p = work / name
        if data is not None:
            p.write_bytes(data)
        out = work / "out" / Path(name).stem / f"{Path(name).stem}.binary"  # a folder per case: no races
        out.parent.mkdir(parents=True, exist_ok=True)
        # bivariate: the campaign is about reading and writing; the valid variants are reconstructed by the method
        # with the least work (no fit search), so the ~70 processes cost little more than reading their input
        cases.append(Case(f"input {name}", "reconstruct", [str(p), *extra, "--out", str(out), "--quiet",
                                                           "--method", "bivariate"], [out], ok=ok,
                          expect=[str(p)] + expect if ok is False else expect))
    # inputs that are not files
    (work / "a-directory.csv").mkdir(exist_ok=True)
    fifo = work / "a-pipe.csv"
    if not fifo.exists():
        os.mkfifo(fifo)
    unreadable = work / "unreadable.csv"
    shutil.copy(good, unreadable)
    unreadable.chmod(0o000)
    for name, path, priv in (("a directory", work / "a-directory.csv", False), ("a pipe", fifo, False),
                             ("/dev/zero", Path("/dev/zero"), False), ("missing file", work / "nowhere.csv", False),
                             ("unreadable file", unreadable, True)):
        out = work / "out" / name.replace(" ", "-").strip("/") / "m.binary"
        out.parent.mkdir(parents=True, exist_ok=True)
        cases.append(Case(f"input {name}", "reconstruct", [str(path), "--out", str(out), "--quiet"], [out],
                          ok=False, unprivileged=priv, expect=[str(path)]))
    # several inputs that overlap, or do not go together
    cases.append(Case("input overlapping files", "reconstruct",
                      [str(good), str(work / "bom-slice.csv"), "--out", str(work / "overlap.binary"),
                       "--quiet"], [work / "overlap.binary"], ok=False, expect=["inputs must not overlap"]))
    # hostile outputs
    o = work / "outputs"
    o.mkdir(exist_ok=True)
    for flag, name in (("--out", "dir.binary"), ("--preview", "dir.exr"), ("--report", "dir.json")):
        (o / name).mkdir(exist_ok=True)
        argv = [str(good), "--quiet", "--method", "bivariate", "--out", str(o / "t.binary")]
        argv = [a if a != str(o / "t.binary") or flag != "--out" else str(o / name) for a in argv]
        if flag != "--out":
            argv += [flag, str(o / name)]
        cases.append(Case(f"output {flag} names a folder", "reconstruct", argv, [o / "t.binary"], ok=False,
                          expect=[f"{flag} {o / name}: is a folder"]))
    (o / "png.png").mkdir(exist_ok=True)
    cases.append(Case("output --preview whose PNG is a folder", "reconstruct",
                      [str(good), "--quiet", "--out", str(o / "p.binary"), "--preview", str(o / "png.exr")],
                      [o / "p.binary", o / "png.exr"], ok=False))
    ro = o / "read-only"
    ro.mkdir(exist_ok=True)
    ro.chmod(0o555)
    cases.append(Case("output in a read-only folder", "reconstruct",
                      [str(good), "--quiet", "--out", str(ro / "m.binary")], [ro / "m.binary"], ok=False,
                      unprivileged=True, expect=["not writable"]))
    cases.append(Case("output in a missing folder", "reconstruct",
                      [str(good), "--quiet", "--out", str(o / "no" / "m.binary")], [], ok=False))
    cases.append(Case("output --out without .binary", "reconstruct",
                      [str(good), "--quiet", "--out", str(o / "m.bin")], [o / "m.bin"], ok=False))
    full = o / "full"
    full.mkdir(exist_ok=True)
    cases.append(Case("output on a full disk (the table)", "reconstruct",
                      [str(good), "--quiet", "--method", "bivariate", "--out", str(full / "m.binary"), "--report",
                       str(full / "m.json")], [full / "m.binary", full / "m.json"], io_fault=True, ok=False,
                      file_size_limit=1_000_000, expect=[str(full / "m.binary")]))
    return cases


# --- bench configs and scene files as hostile files ------------------------------------------------------------


def capture_check_cases(work: Path) -> list[Case]:
    """Hostile files given to ``gonio-capture --check`` as the bench config and as the scene file."""
    work.mkdir(parents=True, exist_ok=True)
    base = CONFIGS["simulated"].read_text()
    scene = (REPO / "configs" / "scenes" / "grazing.toml").read_text()
    rng = np.random.default_rng(5)
    hostile: dict[str, bytes] = {
        "empty": b"",
        "garbage": rng.bytes(4000),
        "latin1": base.replace("blue-plastic", "bleu-\xe9t\xe9").encode("latin-1"),
        "utf16": base.encode("utf-16"),
        "bom": ("\ufeff" + base).encode(),  # accepted (Windows editors write one): see below
        "truncated": base[: len(base) // 2].encode(),
        "nested": ("x = " + "[" * 50000 + "]" * 50000 + "\n").encode(),
        "long-key": (base + "\n[bench2]\n" + "k" * 200_000 + " = 1\n").encode(),
        "huge": (base + "\n# " + "x" * 600_000 + "\n").encode(),
        "merl": np.array([90, 90, 180], "<i4").tobytes() + np.zeros(2000).tobytes(),
        "nul": base.replace("blue-plastic", "blue\x00plastic").encode(),
    }
    cases: list[Case] = []
    scenes = list(hostile.items())[:7]
    for name, data in hostile.items():
        if name == "bom":
            continue
        p = work / f"config-{name}.toml"
        p.write_bytes(data)
        cases.append(Case(f"config {name}", "capture", ["--config", str(p), "--check"], ok=False,
                          expect=[str(p)]))
    for name, data in (("crlf", base.replace("\n", "\r\n").encode()), ("bom", hostile.pop("bom"))):
        p = work / f"config-{name}-ok.toml"
        p.write_bytes(data)
        cases.append(Case(f"config {name}", "capture", ["--config", str(p), "--check"], ok=True))
    (work / "config-dir.toml").mkdir(exist_ok=True)
    fifo = work / "config-pipe.toml"
    if not fifo.exists():
        os.mkfifo(fifo)
    secret = work / "config-unreadable.toml"
    secret.write_text(base)
    secret.chmod(0o000)
    for name, p, priv in (("directory", work / "config-dir.toml", False), ("pipe", fifo, False),
                          ("/dev/zero", Path("/dev/zero"), False), ("unreadable", secret, True),
                          ("missing", work / "none.toml", False)):
        cases.append(Case(f"config {name}", "capture", ["--config", str(p), "--check"], ok=False,
                          unprivileged=priv, expect=[str(p)]))
    for name, data in scenes + [("latin1-scene", scene.replace("grazing", "ras\xe9").encode("latin-1"))]:
        p = work / f"scene-{name}.toml"
        p.write_bytes(data)
        cases.append(Case(f"scene {name}", "capture", ["--config", str(CONFIGS["simulated"]), "--check",
                                                       "--scene", str(p)], ok=False, expect=[str(p)]))
    nested = work / "scene-nested.toml"
    for name, p in (("directory", work / "config-dir.toml"), ("pipe", fifo), ("nested", nested)):
        if name != "nested":
            cases.append(Case(f"scene {name}", "capture", ["--config", str(CONFIGS["simulated"]), "--check",
                                                           "--scene", str(p)], ok=False, expect=[str(p)]))
        cases.append(Case(f"reconstruct scene {name}", "reconstruct",
                          [str(REPO / "tests" / "data" / "implausible-fit-slice.csv"), "--scene", str(p), "--out",
                           str(work / f"scene-{name}.binary"), "--quiet"], [work / f"scene-{name}.binary"],
                          ok=False, expect=[str(p)]))
    return cases


# --- config mutations ----------------------------------------------------------------------------------------------


@dataclass
class Mutation:
    """``where``: the (section path, key) mutated, as it appears in messages (``[axes.light].max_deg``)."""

    name: str
    section: tuple[str, ...]
    key: str | None
    apply: Callable[[dict[str, Any]], None]


_DELETE = object()


def _values_for(v: Any) -> list[tuple[str, Any]]:
    if isinstance(v, bool):
        return [("a string", "yes"), ("a number", 2), ("missing", _DELETE)]
    if isinstance(v, (int, float)):
        return [("a string", "fast"), ("negative", -abs(v) - 1.0), ("zero", 0), ("NaN", math.nan),
                ("infinite", math.inf), ("1e300", 1e300), ("-1e300", -1e300), ("1e-300", 1e-300),
                ("true", True), ("a list", [1, 2]), ("missing", _DELETE), ("10**30", 10**30)]
    if isinstance(v, str):
        return [("a number", 42), ("empty", ""), ("10k characters", "x" * 10_000), ("nonsense", "nonsense"),
                ("missing", _DELETE)]
    if isinstance(v, list):
        return [("empty", []), ("strings", ["a"]), ("1e300s", [1e300]), ("a string", "x"), ("missing", _DELETE),
                ("NaNs", [math.nan])]
    return [("missing", _DELETE)]


def _leaves(d: dict[str, Any], prefix: tuple[str, ...] = ()) -> Iterator[tuple[tuple[str, ...], str, Any]]:
    for k, v in d.items():
        if isinstance(v, dict):
            yield from _leaves(v, (*prefix, k))
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            for i, x in enumerate(v):
                yield from _leaves(x, (*prefix, f"{k}[{i}]"))
        else:
            yield prefix, k, v


def _get(raw: dict[str, Any], section: tuple[str, ...]) -> dict[str, Any]:
    d: Any = raw
    for part in section:
        if part.endswith("]"):
            name, idx = part[:-1].split("[")
            d = d[name][int(idx)]
        else:
            d = d[part]
    return d


def config_mutations(name: str, n: int = 45, seed: int = 2026) -> list[Mutation]:
    """At least ``n`` mutations of the shipped config ``name``: for every section a wrong table, an unknown key
    and a missing required key when it has one; then seeded picks of (leaf key, hostile value), every section
    covered."""
    raw = tomllib.loads(CONFIGS[name].read_text())
    rng = np.random.default_rng(seed)
    leaves = [leaf for leaf in _leaves(raw) if not (name != "simulated" and leaf[0][:1] == ("simulator",))]
    muts: list[Mutation] = []
    sections = sorted({leaf[0] for leaf in leaves if leaf[0]})
    for sec in sections[:6]:
        def unknown(r: dict[str, Any], sec: tuple[str, ...] = sec) -> None:
            _get(r, sec)["bogus_key"] = 1
        muts.append(Mutation(f"[{'.'.join(sec)}] unknown key", sec, "bogus_key", unknown))
    muts.append(Mutation("[bogus] unknown section", (), "bogus", lambda r: r.__setitem__("bogus", {"a": 1})))
    muts.append(Mutation("[motion] not a table", ("motion",), None, lambda r: r.__setitem__("motion", 3)))
    by_section: dict[tuple[str, ...], list[tuple[tuple[str, ...], str, Any]]] = {}
    for leaf in leaves:
        by_section.setdefault(leaf[0], []).append(leaf)
    picks: list[tuple[tuple[str, ...], str, Any, str, Any]] = []
    while len(muts) + len(picks) < n:
        for sec in sorted(by_section):
            sec_leaves = by_section[sec]
            section, key, value = sec_leaves[int(rng.integers(len(sec_leaves)))]
            options = _values_for(value)
            label, new = options[int(rng.integers(len(options)))]
            if (section, key, label) not in {(p[0], p[1], p[3]) for p in picks}:
                picks.append((section, key, value, label, new))
    for section, key, _, label, new in picks:
        def apply(r: dict[str, Any], section: tuple[str, ...] = section, key: str = key, new: Any = new) -> None:
            d = _get(r, section)
            if new is _DELETE:
                del d[key]
            else:
                d[key] = new
        where = f"[{'.'.join(section)}].{key}" if section else key
        muts.append(Mutation(f"{where} {label}", section, key, apply))
    return muts


#: A small plan for the captures of accepted mutations (keeps the campaign fast; the mutated plan key stays).
SMALL_PLAN = {"theta_i_deg": [30.0], "theta_o_min_deg": -70.0, "theta_o_max_deg": 70.0, "theta_o_step_deg": 20.0}
SIMULATOR = {"time_scale": 0.0}
MATERIAL = {"name": "grey", "lobes": [{"type": "lambert", "albedo": 0.5}]}


def mutated_config(name: str, m: Mutation, work: Path) -> Path:
    raw = tomllib.loads(CONFIGS[name].read_text())
    m.apply(raw)
    p = work / f"{name}-{abs(hash(m.name)) % 10**8}.toml"
    p.write_text(tomli_w.dumps(raw), encoding="utf-8")
    for extra in ("panel.csv",):  # files the shipped configs may point to
        src = REPO / "configs" / extra
        if src.exists():
            shutil.copy(src, work / extra)
    return p


def capturable(name: str, m: Mutation, mutated: Path, work: Path) -> Path:
    """The accepted mutated config as a bench file that captures quickly on the simulator: hardware configs get
    transport "simulated" (their own motion hardware) with a material; every plan key but the mutated one
    becomes a small plan."""
    raw = tomllib.loads(mutated.read_text())
    plan = raw.setdefault("plan", {})
    if isinstance(plan, dict):
        keep = m.key if m.section[:1] == ("plan",) else None
        for k, v in SMALL_PLAN.items():
            if k != keep:
                plan[k] = v
        if m.section != ("plan", "adaptive"):
            plan.pop("adaptive", None)
        plan.pop("points", None)
    b = raw.get("bench", {})
    if isinstance(b, dict) and b.get("transport") in ("dynamixel", "serial"):
        b["motion"] = b["transport"]
        b["transport"] = "simulated"
        raw.setdefault("material", copy.deepcopy(MATERIAL))
    sim = raw.setdefault("simulator", {})
    if isinstance(sim, dict):
        sim.update(SIMULATOR)
    p = work / f"capture-{mutated.name}"
    p.write_text(tomli_w.dumps(raw), encoding="utf-8")
    return p


def new_workdir(prefix: str = "gonio-hostile-") -> Path:
    return Path(tempfile.mkdtemp(prefix=prefix))
