"""The GRBL conformance tests (tests/test_grbl_conformance.py, GRBL 1.1h's own code on grbl-sim) beside two CPU
burners, for ``test_grbl_conformance_passes_beside_two_cpu_burners`` there (one module, so that without
``../shared/grbl`` one line says what was skipped). The shim (firmware/grbl/sim/gonio_shim.c) runs GRBL's clock
and interrupts on its main loop's thread, so a busy machine slows grbl-sim down but cannot make it stall, skip a
segment or answer late (what failed on a loaded machine before, each run a different test). The burners are plain
Python loops at the tests' own priority, one per core of a 2-core CI machine.

``GONIO_GRBL_LOAD_TESTS`` (a ``-k`` expression) chooses the conformance tests run here; by default those whose
motion the race broke (moves landing, feed hold and reset, homing, soft and hard limits; not the builds or the
homing alarms), which keep the added CI time near a minute. Run the whole module so with::

    GONIO_GRBL_LOAD_TESTS=all .venv/bin/pytest -q -n 0 tests/test_grbl_conformance.py -k beside_two_cpu_burners
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
BURNERS = 2
DEFAULT_SELECTION = "moves_land or homes_both_arms or limit or feed_hold"


def run_beside_burners() -> None:
    """Run the selection in a child pytest beside :data:`BURNERS` busy loops; AssertionError with its output if
    it does not pass whole."""
    burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(BURNERS)]
    try:
        selection = os.environ.get("GONIO_GRBL_LOAD_TESTS", DEFAULT_SELECTION)
        cmd = [sys.executable, "-m", "pytest", "-q", "-n", "0", "-p", "no:cacheprovider",
               "tests/test_grbl_conformance.py", "-k",
               "not beside_two_cpu_burners" if selection == "all" else selection]
        env = {**os.environ, "GONIO_GRBL_UNDER_LOAD": "1"}
        r = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=1800, env=env)
    finally:
        for b in burners:
            b.kill()
            b.wait()
    tail = r.stdout[-4000:] + r.stderr[-2000:]
    assert r.returncode == 0, tail
    summary = r.stdout.strip().splitlines()[-1]
    assert " passed" in summary and "failed" not in summary and "error" not in summary, tail
