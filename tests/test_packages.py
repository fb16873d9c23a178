"""The packages that replaced modules keep their public names, and their functions run (revolve_table: revolve
tabulated at bin centres)."""

from __future__ import annotations

import numpy as np

from reconstruction.formats import merl
from reconstruction.methods import fit, revolve
from reconstruction.synthetic import synthetic_slice
from tests.test_cli_reconstruct import BLUE_PLASTIC


def test_public_names_of_the_revolve_and_fit_packages_resolve():
    for pkg in (revolve, fit):
        missing = [n for n in pkg.__all__ if not hasattr(pkg, n)]
        assert missing == [], (pkg.__name__, missing)


def test_revolve_table_tabulates_a_slice():
    t = revolve.revolve_table(synthetic_slice(BLUE_PLASTIC, (30.0,)))
    valid = merl.valid_mask()
    assert t.shape == merl.SHAPE and np.all(np.isfinite(t[:, valid])) and np.all(t[:, valid] >= 0)
