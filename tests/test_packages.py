"""The packages that replaced modules keep their public names, and their functions run (revolve_table: revolve
tabulated at bin centres)."""

from __future__ import annotations

import numpy as np
import pytest

from reconstruction.core import merlgrid, merltable
from reconstruction.methods import fit, revolve
from reconstruction.synthetic import synthetic_slice
from tests.test_cli_reconstruct import BLUE_PLASTIC


def test_public_names_of_the_revolve_and_fit_packages_resolve():
    for pkg in (revolve, fit):
        missing = [n for n in pkg.__all__ if not hasattr(pkg, n)]
        assert missing == [], (pkg.__name__, missing)


def test_revolve_table_tabulates_a_slice():
    t = revolve.revolve_table(synthetic_slice(BLUE_PLASTIC, (30.0,)))
    valid = merlgrid.valid_mask()
    assert t.shape == merltable.SHAPE and np.all(np.isfinite(t[:, valid])) and np.all(t[:, valid] >= 0)


def _dotted_names() -> list[tuple[str, str]]:
    """Every ``acquisition.x``, ``simulator.x`` and ``reconstruction.x`` dotted name in backticks in the README,
    docs/*.md and the examples, with the file it is in."""
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    pat = re.compile(r"`((?:acquisition|simulator|reconstruction)(?:\.[A-Za-z_][A-Za-z0-9_]*)+)")
    files = [root / "README.md", *sorted((root / "docs").glob("*.md")), *sorted((root / "examples").glob("*.py"))]
    return sorted({(m, f.name) for f in files for m in pat.findall(f.read_text(encoding="utf-8"))})


@pytest.mark.parametrize("name,page", _dotted_names())
def test_every_dotted_name_in_the_readme_and_docs_resolves(name, page):
    """A name the docs give (``acquisition.plans.measure_points``, ``reconstruction.core.merltable``,
    ``simulator.world.physics``) imports, or is an attribute of the longest module prefix that imports."""
    import importlib

    parts = name.split(".")
    for k in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:k]))
        except ModuleNotFoundError:
            continue
        for attr in parts[k:]:
            assert hasattr(obj, attr), f"{page}: `{name}`: {'.'.join(parts[:k])} has no {attr}"
            obj = getattr(obj, attr)
        return
    raise AssertionError(f"{page}: `{name}` does not import")
