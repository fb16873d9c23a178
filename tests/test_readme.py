"""The README as a user meets it: its snippets and command lines run, the figures it quotes from the demo are what
the demo prints, and its links (and the docs pages' links) lead somewhere.

* The README has Python snippets (tests/test_tour.py runs them, with the tour's command lines, in a temporary
  folder).
* The demo (the README's first command: the capture on the simulated bench, then ``gonio-reconstruct --method
  auto``) is run into a temporary folder, twice for the capture, which must give the same samples (the simulator
  is seeded and its time jumps). Every figure of the README's demo paragraph, the table's size and the ``--check``
  estimates of the shipped configs it quotes are compared with what the commands print (the console, and the
  report ``material.json`` that the first command writes), to the precision the README prints them with. One
  failure lists every figure that differs with its new value, so a behaviour change only asks for the README's
  numbers to be updated; a number in the demo paragraph that no check covers is a failure too.
* Every ``gonio-*`` command line of the README's and the docs pages' ``sh`` blocks is accepted by its command's
  parser (and, for ``gonio-reconstruct``, by its rules on which arguments go together). The README's are run by
  tests/test_tour.py; of the docs pages', the cheap ones are run here: every ``--check`` and ``gonio-sim
  check``. The test ids say which: ``run:`` or ``parse:``.

After a change of behaviour moves a demo figure, the failure names each figure that differs and the value the demo
prints now: update the README's number (and nothing else) to that value.
"""

from __future__ import annotations

import json
import math
import re
import shlex
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
DOCS = sorted((ROOT / "docs").glob("*.md"))
BLOCKS = re.findall(r"```python\n(.*?)```", README, flags=re.S)
MAX_LINES = 300
CLIS = {"gonio-capture": "acquisition.cli", "gonio-reconstruct": "reconstruction.cli", "gonio-sim": "simulator.cli",
        "gonio-compare": "reconstruction.report.compare"}
SHIPPED_CONFIGS = ("simulated", "dynamixel-bench", "serial-bench")


def sh_blocks(text: str) -> list[str]:
    return re.findall(r"```sh\n(.*?)```", text, flags=re.S)


def gonio_commands(block: str) -> list[list[str]]:
    """The ``gonio-*`` command lines of an ``sh`` block as argument lists (``.venv/bin/`` dropped, ``\\``
    continuations joined, ``#`` comments and the non-gonio parts of ``&&`` chains left out)."""
    out = []
    for line in block.replace("\\\n", " ").splitlines():
        for part in line.split("&&"):
            words = shlex.split(part, comments=True)
            if words and words[0].removeprefix(".venv/bin/") in CLIS:
                out.append([words[0].removeprefix(".venv/bin/"), *words[1:]])
    return out


def cli(name: str) -> list[str]:
    """The command to run ``name``: the console script beside the interpreter running the tests (what the README's
    ``.venv/bin/NAME`` is), or the module through that interpreter."""
    exe = Path(sys.executable).parent / name
    return [str(exe)] if exe.exists() else [sys.executable, "-m", CLIS[name]]


def run(argv: list[str], cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cli(argv[0]) + argv[1:], cwd=cwd, capture_output=True, text=True, timeout=timeout)


# --- the README's shape, its Python snippets, its test command ---------------------------------------------------


def test_the_readme_is_short():
    assert len(README.splitlines()) <= MAX_LINES, f"README.md has {len(README.splitlines())} lines (at most 300)"


def test_the_readme_has_python_snippets():
    assert len(BLOCKS) >= 2


def test_the_readme_test_command_is_the_one_ci_runs():
    ci = [ln for ln in (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()
          if ln.strip() and not ln.startswith("#") and not ln.startswith(("set ", "cd "))]
    assert ci == ["sh scripts/system-packages.sh && python3 -m venv .venv && .venv/bin/pip install -q -e '.[test]' "
                  "&& .venv/bin/python -m pytest -q"]
    assert ci[0] in [b.strip() for b in sh_blocks(README)], "the README's test command is not the line .ci/run runs"


# --- the demo: run as the README's first command does, figures checked ----------------------------------------------


def first_command() -> list[list[str]]:
    """The README's first ``sh`` block's gonio commands: the demo's capture and its reconstruction."""
    cmds = gonio_commands(sh_blocks(README)[0])
    assert [c[0] for c in cmds] == ["gonio-capture", "gonio-reconstruct"], cmds
    assert sh_blocks(README)[0].startswith("python3 -m venv .venv && .venv/bin/pip install -q -e . && ")
    return cmds


def into(argv: list[str], demo: Path) -> list[str]:
    """``argv`` with the README's ``out/demo`` folder replaced by ``demo``."""
    return [a.replace("out/demo", str(demo)) for a in argv]


@dataclass
class Demo:
    """What the demo's commands printed and wrote."""

    folder: Path
    capture: str                      # gonio-capture's console output
    capture_again: str
    reconstruct: str                  # gonio-reconstruct's console output
    report: dict[str, Any]            # material.json
    checks: dict[str, str] = field(default_factory=dict)   # config name -> gonio-capture --check output


def run_demo(tmp: Path) -> Demo:
    capture, reconstruct = first_command()
    outputs = {}
    for name in ("demo", "demo-again"):
        r = run(into(capture, tmp / name), ROOT)
        assert r.returncode == 0, f"the README's capture failed:\n{r.stdout}\n{r.stderr[-2000:]}"
        outputs[name] = r.stdout + r.stderr
    r = run(into(reconstruct, tmp / "demo"), ROOT)
    assert r.returncode == 0, f"the README's reconstruction failed:\n{r.stderr[-2000:]}"
    d = Demo(tmp / "demo", outputs["demo"], outputs["demo-again"], r.stdout + r.stderr,
             json.loads((tmp / "demo" / "material.json").read_text(encoding="utf-8")))
    for name in SHIPPED_CONFIGS:
        c = run(["gonio-capture", "--config", f"configs/{name}.toml", "--check"], ROOT)
        assert c.returncode == 0, f"gonio-capture --config configs/{name}.toml --check failed:\n{c.stderr[-2000:]}"
        d.checks[name] = c.stdout + c.stderr
    return d


@pytest.fixture(scope="module")
def demo(tmp_path_factory, request) -> Demo:
    """The demo, run once per test session (:func:`shared_demo`)."""
    return shared_demo(tmp_path_factory, request)


_RUN: dict[str, Demo] = {}


def shared_demo(tmp_path_factory: pytest.TempPathFactory, request: pytest.FixtureRequest) -> Demo:
    """The demo, run once per test session (tests/test_tour.py uses it too): under pytest-xdist the first worker
    runs it into the session's shared folder (under an flock) and the others read what it printed."""
    worker = getattr(request.config, "workerinput", None)
    if worker is None:
        if "demo" not in _RUN:  # one run for the modules that use it
            _RUN["demo"] = run_demo(tmp_path_factory.mktemp("readme-demo"))
        return _RUN["demo"]
    import fcntl

    shared = tmp_path_factory.getbasetemp().parent / "readme-demo"  # the session's folder, shared by its workers
    shared.mkdir(exist_ok=True)
    with open(shared / "lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        done = shared / "demo.json"
        if not done.exists():
            d = run_demo(shared)
            done.write_text(json.dumps(d.__dict__, default=str), encoding="utf-8")
        saved = json.loads(done.read_text(encoding="utf-8"))
    return Demo(**{**saved, "folder": Path(saved["folder"])})


@pytest.mark.slow
def test_the_demo_capture_is_deterministic(demo):
    from reconstruction.formats.slicefile import read_slice

    a, b = read_slice(demo.folder / "slice.csv"), read_slice(demo.folder.parent / "demo-again" / "slice.csv")
    for column in ("theta_i_deg", "theta_o_deg", "values", "std", "repeats"):
        assert np.array_equal(getattr(a, column), getattr(b, column)), f"two demo captures differ in {column}"
    assert bench_time(demo.capture) == bench_time(demo.capture_again)


def grab(pattern: str, text: str, what: str) -> str:
    m = re.search(pattern, text)
    assert m, f"{what}: no match of {pattern!r} in:\n{text[-3000:]}"
    return m.group(1)


def bench_time(out: str) -> float:
    return float(grab(r"simulated capture time ([\d.]+) s of bench time", out, "gonio-capture"))


def estimate(out: str) -> float:
    return float(grab(r"estimated ([\d.]+) s", out, "gonio-capture"))


def check_estimate(out: str) -> float:
    return float(grab(r"estimated bench time: ([\d.]+) s", out, "gonio-capture --check"))


def lobe(report: dict[str, Any], kind: str) -> dict[str, Any]:
    return next(p for p in report["parameters"] if p["type"] == kind)


def held_out_percent(report: dict[str, Any], label: str) -> float:
    scores = {s["label"]: s["held_out_relative_rmse_cos"] for s in report["cross_validation"]["scores"]}
    return 100.0 * scores[label]


def truth(kind: str, key: str) -> float:
    """A parameter of the demo's simulated material (configs/simulated.toml), which the README calls true."""
    cfg = tomllib.loads((ROOT / "configs" / "simulated.toml").read_text(encoding="utf-8"))
    return float(next(lb[key] for lb in cfg["material"]["lobes"] if lb["type"] == kind))


Getter = Callable[[Demo], Any]
N = r"(\d+(?:,\d{3})*(?:\.\d+)?)"  # a figure as the README prints it: 12, 0.1509, 34,992,012
# (what, where in the README: "demo" = the paragraph "What the demo prints ...", "readme" = anywhere,
#  a pattern whose groups are README figures, one getter per group: what the commands printed)
FIGURES: list[tuple[str, str, str, list[Getter]]] = [
    ("samples captured", "demo", r"measures (\d+) samples",
     [lambda d: int(grab(r"captured (\d+) new sample", d.capture, "gonio-capture"))]),
    ("plan points not measurable", "demo", r"lists (\d+) plan points as not measurable",
     [lambda d: int(grab(r"(\d+) plan point\(s\) not measurable", d.capture, "gonio-capture"))]),
    ("simulated bench time, estimate", "demo", rf"takes {N} s of simulated bench time against {N} s estimated",
     [lambda d: bench_time(d.capture), lambda d: estimate(d.capture)]),
    ("method auto chose, its model", "demo", r"picks `(\w+)` with the model `([^`]+)`",
     [lambda d: d.report["method"], lambda d: d.report["details"]["model"]]),
    ("held-out error of the chosen method", "demo", rf"predicts the held-out samples to {N} %",
     [lambda d: held_out_percent(d.report, d.report["cross_validation"]["chosen_label"])]),
    *[(f"held-out error of {m}", "demo", rf"`{m}` {N} %", [lambda d, m=m: held_out_percent(d.report, m)])
      for m in ("microfacet", "revolve", "bivariate")],
    ("ggx alpha", "demo", rf"alpha {N} ± {N} \(true {N}\)",
     [lambda d: lobe(d.report, "ggx")["alpha"], lambda d: lobe(d.report, "ggx")["alpha_std"],
      lambda d: truth("ggx", "alpha")]),
    ("index of refraction", "demo", rf"index of refraction {N} ± {N}",
     [lambda d: lobe(d.report, "ggx")["ior"], lambda d: lobe(d.report, "ggx")["ior_std"]]),
    ("f0", "demo", rf"f0 {N} ± {N} \(true {N}\)",
     [lambda d: lobe(d.report, "ggx")["f0"], lambda d: lobe(d.report, "ggx")["f0_std"],
      lambda d: truth("ggx", "f0")]),
    ("lambert albedo", "demo", rf"lambert albedo {N} ± {N}",
     [lambda d: lobe(d.report, "lambert")["albedo"][0], lambda d: lobe(d.report, "lambert")["albedo_std"][0]]),
    ("the table's size", "readme", rf"the MERL table, {N} bytes",
     [lambda d: int(grab(rf"\({N} bytes\)", d.reconstruct, "gonio-reconstruct").replace(",", ""))]),
    ("--check of the demo config", "readme", rf"{N} s for the demo \(`configs/simulated.toml`\)",
     [lambda d: check_estimate(d.checks["simulated"])]),
    ("--check of dynamixel-bench.toml", "readme", rf"{N} s for `configs/dynamixel-bench.toml`",
     [lambda d: check_estimate(d.checks["dynamixel-bench"])]),
    ("--check of serial-bench.toml", "readme", rf"{N} s for `configs/serial-bench.toml` before its adaptive",
     [lambda d: check_estimate(d.checks["serial-bench"])]),
]


def flat(text: str) -> str:
    return re.sub(r"\s+", " ", text)


def demo_paragraph() -> str:
    m = re.search(r"\nWhat the demo prints.*?\n\n", README, flags=re.S)
    assert m, "the README has no paragraph starting 'What the demo prints'"
    return flat(m.group(0))


def same(quoted: str, value: Any) -> tuple[bool, str]:
    """Whether the README's ``quoted`` figure is ``value`` at the README's precision; and ``value`` so printed."""
    if isinstance(value, str):
        return quoted == value, value
    q = quoted.replace(",", "")
    decimals = len(q.split(".")[1]) if "." in q else 0
    shown = f"{value:,.{decimals}f}" if "," in quoted else f"{value:.{decimals}f}"
    return math.isclose(float(q), round(float(value), decimals), abs_tol=0.5 * 10.0 ** -(decimals + 3)), shown


def test_the_readme_quotes_the_demo_as_it_prints(demo):
    texts = {"demo": demo_paragraph(), "readme": flat(README)}
    problems, covered = [], []
    for what, where, pattern, getters in FIGURES:
        matches = list(re.finditer(pattern, texts[where]))
        if len(matches) != 1:
            shown = pattern.replace(N, "<figure>")
            problems.append(f"{what}: the README should quote it once ({len(matches)} matches of {shown!r})")
            continue
        m = matches[0]
        for k, get in enumerate(getters, start=1):
            if where == "demo":
                covered.append(m.span(k))
            ok, shown = same(m.group(k), get(demo))
            if not ok:
                problems.append(f"{what}: the README says {m.group(k)}, the demo prints {shown}")
    text = texts["demo"]
    for m in re.finditer(r"(?<![\w.])" + N[1:-1], text):
        if not any(a <= m.start() and m.end() <= b for a, b in covered):
            problems.append(f"the demo paragraph quotes {m.group(0)!r} ({text[max(0, m.start() - 40):m.end() + 20]!r})"
                            " and no check covers it: add it to FIGURES or leave it out")
    assert not problems, "README.md against the demo's output:\n  " + "\n  ".join(problems)


# --- every gonio command line of the README and the docs -------------------------------------------------------------


def every_command() -> list[tuple[str, list[str]]]:
    cmds = [("README.md", c) for b in sh_blocks(README)[1:] for c in gonio_commands(b)]  # the first: the demo's
    for page in DOCS:
        blocks = sh_blocks(page.read_text(encoding="utf-8"))
        cmds += [(f"docs/{page.name}", c) for b in blocks for c in gonio_commands(b)]
    return cmds


COMMANDS = every_command()


def how(source: str, argv: list[str]) -> str:
    """"run" when a test runs the line (the README's tour: tests/test_tour.py; a docs page's line when it is
    cheap: every ``--check`` and ``gonio-sim check``), else "parse"."""
    name, args = argv[0], argv[1:]
    if source == "README.md":
        return "run"
    if name == "gonio-capture" and "--check" in args:
        return "run"
    if name == "gonio-sim" and args[:1] == ["check"]:
        return "run"
    return "parse"


def test_the_readme_and_docs_have_gonio_commands():
    names = {c[0] for src, c in COMMANDS if src == "README.md"}
    assert names == set(CLIS), names


@pytest.mark.parametrize(("source", "argv"), COMMANDS,
                         ids=[f"{how(s, c)}:{s}:{shlex.join(c)[:80]}" for s, c in COMMANDS])
def test_the_command_line_parses(source, argv, capsys):
    import importlib

    parser = importlib.import_module(CLIS[argv[0]]).build_parser()
    try:
        args = parser.parse_args(argv[1:])
    except SystemExit:
        pytest.fail(f"{source}: `{shlex.join(argv)}` is refused by {argv[0]}: {capsys.readouterr().err.strip()}")
    if argv[0] == "gonio-reconstruct":  # what _main checks before any work
        from reconstruction.formats.exports import wants_outputs

        ok = (args.batch and not args.inputs and not args.out) or (args.inputs and (args.out or wants_outputs(args)))
        assert ok, f"{source}: `{shlex.join(argv)}`: gonio-reconstruct needs INPUT and an output, or --batch alone"


@pytest.mark.parametrize(("source", "argv"), [c for c in COMMANDS if how(*c) == "run" and c[0] != "README.md"],
                         ids=lambda v: shlex.join(v)[:80] if isinstance(v, list) else v)
def test_the_cheap_command_line_runs(source, argv):
    r = run(argv, ROOT, timeout=120)
    assert r.returncode == 0, f"{source}: `{shlex.join(argv)}` exits {r.returncode}:\n{r.stderr[-2000:]}"


# --- links -----------------------------------------------------------------------------------------------------------


def slug(heading: str) -> str:
    """GitHub's anchor of a markdown heading."""
    h = re.sub(r"[`*]", "", heading.strip().lower())
    return re.sub(r"[^\w\- ]", "", h).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    text = re.sub(r"```.*?```", "", page.read_text(encoding="utf-8"), flags=re.S)
    return {slug(m.group(1)) for m in re.finditer(r"^#{1,6} (.+)$", text, flags=re.M)}


def links(page: Path) -> list[str]:
    text = re.sub(r"```.*?```", "", page.read_text(encoding="utf-8"), flags=re.S)
    text = re.sub(r"`[^`\n]*`", "", text)
    return re.findall(r"\]\(([^)\s]+)\)", text)


PAGES = [ROOT / "README.md", *DOCS]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_relative_links_lead_to_files_and_headings(page):
    bad = []
    for target in links(page):
        if re.match(r"^[a-z]+:", target):  # http:, https:, mailto:
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            bad.append(f"{target}: no such file")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            bad.append(f"{target}: no heading #{anchor} in {dest.relative_to(ROOT)}")
    assert not bad, f"{page.relative_to(ROOT)}:\n  " + "\n  ".join(bad)


def test_every_docs_page_says_how_its_figures_are_made():
    """Each docs page names, near its top, the command that regenerates its figures (or that it has none)."""
    missing = []
    for page in DOCS:
        head = "\n".join(page.read_text(encoding="utf-8").splitlines()[:12])
        if not re.search(r"Regenerate|Produced by|Figures on this page|no measured figures|no figures", head):
            missing.append(page.name)
    assert not missing, f"docs pages that do not say which command makes their figures: {missing}"
