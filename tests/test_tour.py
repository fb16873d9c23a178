"""The README's "A five-minute tour" runs as written, top to bottom, after the README's first command.

Its blocks (``sh`` and ``python``) are read from the README, so the README cannot drift from what runs, and run in
their order in a temporary folder that holds what the repository gives a user: ``configs/``, ``examples/`` and the
first command's ``out/demo`` (the demo of tests/test_readme.py, run once per session). Every command must be
written with ``.venv/bin/`` (a fresh shell has no ``gonio-*`` on its PATH), exit 0, write what it names, and no two
commands may name the same output (but ``--resume``, which continues its capture). ``gonio-sim serve`` serves until
stopped: it is started, must print its ports, and is stopped with SIGINT as a user's Ctrl-C.
"""

from __future__ import annotations

import importlib
import json
import re
import shlex
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

readme = sys.modules.get("test_readme") or importlib.import_module("tests.test_readme")

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
PREFIX = ".venv/bin/"
#: options naming a file or folder a command writes
OUTPUTS = ("--out", "--preview", "--report", "--html", "--rgl", "--zemax", "--export-mitsuba", "--export-json",
           "--uncertainty", "--principled", "--gltf", "--materialx", "--blender", "--png", "--json", "--out-dir")


def tour_blocks() -> list[tuple[str, str]]:
    """The tour section's code blocks in order: (language, text)."""
    m = re.search(r"\n## A five-minute tour\n(.*?)\n## ", README, flags=re.S)
    assert m, "the README has no section '## A five-minute tour'"
    return re.findall(r"```(sh|python)\n(.*?)```", m.group(1), flags=re.S)


def sh_lines(block: str) -> list[list[str]]:
    """The command lines of an ``sh`` block (comments dropped) as argument lists."""
    return [words for line in block.replace("\\\n", " ").splitlines() if (words := shlex.split(line, comments=True))]


def outputs(argv: list[str]) -> list[str]:
    """What a command line writes: the values of its :data:`OUTPUTS` options (a preview's PNG beside it)."""
    out = [argv[k + 1] for k, a in enumerate(argv[:-1]) if a in OUTPUTS]
    out += [str(Path(argv[k + 1]).with_suffix(".png")) for k, a in enumerate(argv[:-1]) if a == "--preview"]
    return out


def test_the_tour_commands_are_written_to_run_from_a_fresh_shell():
    """Every tour command names the environment's executable (``.venv/bin/``), and no two name the same output."""
    seen: dict[str, str] = {}
    problems = []
    for lang, block in tour_blocks():
        if lang != "sh":
            continue
        for argv in sh_lines(block):
            line = shlex.join(argv)
            if not argv[0].startswith(PREFIX):
                problems.append(f"`{line}` does not start with {PREFIX} (not on a fresh shell's PATH)")
            if "--resume" in argv:
                continue  # continues the capture before it
            for o in outputs(argv):
                key = o.rstrip("/")
                if key in seen:
                    problems.append(f"`{line}` writes {o}, which `{seen[key]}` wrote already")
                seen[key] = line
    assert not problems, "README tour:\n  " + "\n  ".join(problems)


def run_serve(argv: list[str], cwd: Path) -> None:
    """``gonio-sim serve``: started, its ports read from its first line, stopped as Ctrl-C stops it."""
    p = subprocess.Popen(readme.cli(argv[0]) + argv[1:], cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True)
    try:
        first = p.stdout.readline() if p.stdout else ""
        ports = json.loads(first)
        assert {"dynamixel", "serial"} <= set(ports), f"`{shlex.join(argv)}` printed {first!r}"
    finally:
        p.send_signal(signal.SIGINT)
        try:
            p.communicate(timeout=30)
        except subprocess.TimeoutExpired:  # pragma: no cover - a hung server
            p.kill()
            p.communicate()


@pytest.fixture
def tour(tmp_path_factory, request, tmp_path) -> Path:
    """A folder as a user has it after the README's first command: the repository's configs and examples and the
    demo's ``out/demo``."""
    demo = readme.shared_demo(tmp_path_factory, request)
    for name in ("configs", "examples"):
        shutil.copytree(ROOT / name, tmp_path / name, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copytree(demo.folder, tmp_path / "out" / "demo")
    return tmp_path


@pytest.mark.slow
def test_the_tour_runs_as_written(tour):
    ran = 0
    for lang, block in tour_blocks():
        if lang == "python":
            r = subprocess.run([sys.executable, "-c", block], cwd=tour, capture_output=True, text=True, timeout=300)
            assert r.returncode == 0, f"the tour's Python block failed:\n{block}\n{r.stderr[-2000:]}"
            ran += 1
            continue
        for argv in sh_lines(block):
            argv = [argv[0].removeprefix(PREFIX), *argv[1:]]
            if argv[:2] == ["gonio-sim", "serve"]:
                run_serve(argv, tour)
            else:
                r = readme.run(argv, tour)
                assert r.returncode == 0, (f"the tour's `{shlex.join(argv)}` exits {r.returncode}:\n"
                                           f"{r.stdout[-1500:]}\n{r.stderr[-2000:]}")
            missing = [o for o in outputs(argv) if not (tour / o).exists()]
            assert not missing, f"`{shlex.join(argv)}` did not write {missing}"
            ran += 1
    assert ran >= 15, f"the tour ran {ran} blocks and commands"
    assert sorted(p.name for p in (tour / "out" / "materials").glob("*.binary")) == [
        "glossy-red.binary", "matte-grey.binary"]
