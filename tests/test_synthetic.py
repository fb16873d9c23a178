"""reconstruction.synthetic: in-plane slices of a known material, as the bench would take them."""

import numpy as np

from reconstruction.core.geometry import inplane_to_dirs
from reconstruction.core.models import Material
from reconstruction.synthetic import synthetic_slice

GREY = Material.from_dict({"name": "grey", "lobes": [{"type": "lambert", "albedo": 0.5},
                                                     {"type": "ggx", "alpha": 0.2, "specular": 0.3}]})


def test_geometry_and_values():
    s = synthetic_slice(GREY, (30.0, 60.0), step_deg=5.0, blind_spot_deg=4.0)
    assert s.channels == ["value"] and s.quantity == "brdf"
    for ti in (30.0, 60.0):
        to = s.theta_o_deg[s.theta_i_deg == ti]
        expected = np.arange(-80.0, 80.0 + 1e-9, 5.0)
        np.testing.assert_array_equal(to, expected[np.abs(expected + ti) > 4.0])  # no retro blind spot
    assert list(s.theta_i_deg[:2]) == [30.0, 30.0] and s.theta_i_deg[-1] == 60.0  # incidence by incidence
    np.testing.assert_array_equal(s.values, GREY.eval(*inplane_to_dirs(np.radians(s.theta_i_deg),
                                                                       np.radians(s.theta_o_deg))))
    assert not s.std.any()


def test_explicit_angles_channels_and_noise():
    s = synthetic_slice(GREY, [20.0], theta_o_deg=[-20.0, -10.0, 0.0, 40.0])
    np.testing.assert_array_equal(s.theta_o_deg, [-10.0, 0.0, 40.0])
    rgb = Material.from_dict({"name": "rgb", "lobes": [{"type": "lambert", "albedo": [0.1, 0.2, 0.3]}]})
    assert synthetic_slice(rgb).channels == ["R", "G", "B"]
    spec = Material.from_dict({"name": "spec", "lobes": [
        {"type": "lambert", "albedo": {"wavelengths_nm": [450, 550, 650], "values": [0.1, 0.2, 0.3]}}]})
    assert synthetic_slice(spec).channels == ["450nm", "550nm", "650nm"]
    clean = synthetic_slice(GREY)
    a = synthetic_slice(GREY, noise=0.05, noise_floor=1e-3, seed=7)
    b = synthetic_slice(GREY, noise=0.05, noise_floor=1e-3, seed=7)
    np.testing.assert_array_equal(a.values, b.values)  # reproducible
    np.testing.assert_allclose(a.std, 0.05 * np.abs(clean.values) + 1e-3)
    z = (a.values - clean.values) / a.std
    assert 0.7 < np.std(z) < 1.3 and not np.array_equal(a.values, synthetic_slice(GREY, noise=0.05, seed=8).values)
