"""The real tools the principled-material exporters are checked with, installed on first use (import as
``tests.external_tools``; never skipped unless asked: a tool that cannot be installed fails the test with the
reason, and ``GONIO_TESTS_NO_EXTERNAL=1`` (:data:`NO_EXTERNAL`) skips the tests that need one, installing nothing).

- Blender as a Python module (``bpy``): the builds for Python 3.11 (Blender 4.2 to 5.0) require numpy < 2, and
  colour-science (a dependency of gonio-brdf) requires numpy >= 2, so bpy cannot live in the project's
  environment: it gets its own (``python -m venv`` + ``pip install`` of :data:`BPY_REQUIREMENT`: about 12 s and
  11 s of CPU, 950 MB), where tests/blender_render.py runs as a child process.
- The Khronos glTF validator (the npm package ``gltf-validator``, Dart compiled to JavaScript), run with node:
  ``npm install`` of :data:`GLTF_VALIDATOR` (about 1 s once).

Both live in the user's cache (:data:`TOOLS`, ``$XDG_CACHE_HOME/gonio-brdf-tests`` else
``~/.cache/gonio-brdf-tests``, one folder per tool version and Python), outside the test environment, so that a
fresh clone's ``.venv`` (every CI run) reuses them: a machine builds them once. A file lock keeps the two
pytest-xdist workers (and concurrent runs) from installing at once; a build that did not finish (no ``.ready``) or
whose interpreter is gone is built again. ``GONIO_BLENDER_PYTHON`` may name a Python that already has bpy.
"""

from __future__ import annotations

import fcntl
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

#: Blender 4.5 LTS as a Python module, built for Python 3.11
BPY_REQUIREMENT = "bpy>=4.5,<4.6"
#: the Khronos glTF validator, the npm package's newest release
GLTF_VALIDATOR = "gltf-validator@2.0.0-dev.3.10"
#: where the tools are built (read once, at import: some tests point XDG_CACHE_HOME at a fresh folder)
TOOLS = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "gonio-brdf-tests"
_PY = f"py{sys.version_info.major}.{sys.version_info.minor}"
#: the environment variable that skips the tests needing these tools (set to 1) instead of installing them
NO_EXTERNAL = "GONIO_TESTS_NO_EXTERNAL"


def _skip_if_not_wanted(tool: str) -> None:
    """Skip the calling test, with a plain reason, when :data:`NO_EXTERNAL` is set to anything but 0 / empty."""
    if os.environ.get(NO_EXTERNAL, "").strip() not in ("", "0"):
        import pytest

        pytest.skip(f"{NO_EXTERNAL}={os.environ[NO_EXTERNAL]}: {tool} is not installed (unset it to test with it)")


@contextmanager
def _locked(name: str) -> Iterator[None]:
    TOOLS.mkdir(parents=True, exist_ok=True)
    with open(TOOLS / f".{name}.lock", "w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _run(cmd: list[str], what: str) -> None:
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    if r.returncode != 0:
        raise RuntimeError(f"installing {what} failed ({' '.join(cmd)}): {(r.stderr or r.stdout)[-2000:]}")


def blender_python() -> str:
    """A Python interpreter that imports ``bpy`` (built on first use, see the module docstring)."""
    given = os.environ.get("GONIO_BLENDER_PYTHON")
    if given:
        return given
    _skip_if_not_wanted(f"Blender's bpy ({BPY_REQUIREMENT}, about 950 MB)")
    env = TOOLS / f"blender-{_PY}-{BPY_REQUIREMENT.replace('>=', '-').replace(',<', '-')}"
    py = env / "bin" / "python"
    with _locked("blender"):
        if not ((env / ".ready").exists() and py.exists()):
            if env.exists():
                shutil.rmtree(env)
            base = getattr(sys, "_base_executable", None) or sys.executable
            _run([base, "-m", "venv", str(env)], "a venv for Blender")
            _run([str(py), "-m", "pip", "install", "-q", BPY_REQUIREMENT], BPY_REQUIREMENT)
            _run([str(py), "-c", "import bpy"], "bpy (import check)")
            (env / ".ready").write_text(BPY_REQUIREMENT + "\n")
    return str(py)


def gltf_validator() -> tuple[str, Path]:
    """(node, the gltf-validator package folder), installed on first use."""
    _skip_if_not_wanted(f"the Khronos glTF validator (npm {GLTF_VALIDATOR})")
    node, npm = shutil.which("node"), shutil.which("npm")
    if not node or not npm:
        raise RuntimeError("the glTF validator runs on Node.js: install node and npm (Debian: apt-get install "
                           "nodejs npm)")
    prefix = TOOLS / f"npm-{GLTF_VALIDATOR}"
    pkg = prefix / "node_modules" / "gltf-validator"
    with _locked("npm"):
        if not (pkg / "package.json").exists():
            _run([npm, "install", "--prefix", str(prefix), "--no-audit", "--no-fund", "--no-save", GLTF_VALIDATOR],
                 GLTF_VALIDATOR)
    return node, pkg


_VALIDATE_JS = """
const fs = require('fs');
const validator = require(process.argv[1]);
const data = new Uint8Array(fs.readFileSync(process.argv[2]));
validator.validateBytes(data, {maxIssues: 100})
  .then((r) => { process.stdout.write(JSON.stringify(r)); })
  .catch((e) => { process.stderr.write(String(e)); process.exit(1); });
"""


def validate_gltf(path: str | Path) -> dict:
    """The Khronos validator's report (a dict with ``issues``: numErrors, numWarnings, messages) of a .gltf."""
    import json

    node, pkg = gltf_validator()
    r = subprocess.run([node, "-e", _VALIDATE_JS, str(pkg), str(path)], capture_output=True, text=True, timeout=120)
    if r.returncode != 0:
        raise RuntimeError(f"gltf-validator failed on {path}: {r.stderr[-2000:]}")
    return json.loads(r.stdout)
