"""Rows out of the plane of incidence in CSV inputs (issue 50): a tilted-sample sweep in a slice file's ``tilt_deg``
column or a generic table's, and azimuth columns, land at the right Rusinkiewicz angles and reach every method."""

from __future__ import annotations

import numpy as np
import pytest

from reconstruction import pipeline
from reconstruction.core.geometry import half_diff_from_dirs, tilted_to_dirs
from reconstruction.core.models import Material
from reconstruction.core.samples import SliceWithPoints, everywhere, points_anywhere
from reconstruction.core.slicedata import SliceError
from reconstruction.formats import inputs
from reconstruction.formats.slicefile import read_slice
from reconstruction.methods import Options

MAT = Material.from_dict({"name": "plastic", "lobes": [{"type": "lambert", "albedo": [0.2, 0.3, 0.5]},
                                                       {"type": "ggx", "specular": 0.04, "alpha": 0.2}]})


def _rows(tilt: float, arm_i: float = 40.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    b = np.arange(-70.0, 71.0, 10.0)
    b = b[np.abs(b + arm_i) >= 4.0]
    wi, wo = tilted_to_dirs(np.radians(arm_i), np.radians(b), np.radians(tilt))
    return np.full(b.size, arm_i), b, MAT.eval(wi, wo)


def _slice_file(path, sweeps, tilt_column=True):
    lines = ["# gonio-brdf slice", '# meta: {"format_version": 1, "quantity": "brdf"}',
             "theta_i_deg,theta_o_deg," + ("tilt_deg," if tilt_column else "") + "R,G,B,R_std,G_std,B_std,repeats,"
             "unix_time_s"]
    for tilt in sweeps:
        for a, b, f in zip(*_rows(tilt), strict=True):
            lines.append(f"{a:g},{b:g}," + (f"{tilt:g}," if tilt_column else "") + ",".join(f"{x:.9g}" for x in f)
                         + ",0,0,0,4,1795000000")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_tilted_sweep_in_a_slice_file_lands_at_its_rusinkiewicz_angles(tmp_path):
    s = inputs.load_inputs([_slice_file(tmp_path / "s.csv", (0.0, 30.0))]).slice
    assert isinstance(s, SliceWithPoints)
    pts = points_anywhere(s)
    assert pts is not None and len(pts) == 2 * len(s)  # the in-plane sweep is the slice; both are points
    np.testing.assert_allclose(np.unique(s.theta_i_deg), [40.0])
    # the tilted detector at arm angle b = 40 (the arms' mirror position): the half vector is the tilted normal's
    # direction in the bench plane, theta_h = the tilt, theta_d = the arm angle, phi_d = 90 deg
    wi, wo = tilted_to_dirs(np.radians(40.0), np.radians(40.0), np.radians(30.0))
    k = int(np.argmin(np.linalg.norm(pts.wo - wo, axis=1) + np.linalg.norm(pts.wi - wi, axis=1)))
    th, _, td, pd = half_diff_from_dirs(pts.wi[k], pts.wo[k])
    np.testing.assert_allclose(np.degrees([th, td, abs(pd)]), [30.0, 40.0, 90.0], atol=1e-9)
    # every point's values are the material's at its directions (nothing placed in the plane by mistake)
    np.testing.assert_allclose(pts.values, MAT.eval(pts.wi, pts.wo), rtol=1e-7)
    assert np.degrees(np.arccos(pts.wi[len(s):, 2])).min() == pytest.approx(np.degrees(np.arccos(
        np.cos(np.radians(40.0)) * np.cos(np.radians(30.0)))))


def test_an_old_slice_file_reads_unchanged(tmp_path):
    s = read_slice(_slice_file(tmp_path / "old.csv", (0.0,), tilt_column=False))
    assert type(s).__name__ == "Slice" and len(s) == len(_rows(0.0)[0])
    assert not isinstance(inputs.load_inputs([tmp_path / "old.csv"]).slice, SliceWithPoints)


def test_a_generic_table_with_azimuths_and_one_with_a_tilt_give_the_same_points(tmp_path):
    a, b, f = _rows(30.0)
    wi, wo = tilted_to_dirs(np.radians(a), np.radians(b), np.radians(30.0))
    ti, to = np.degrees(np.arccos(wi[:, 2])), np.degrees(np.arccos(wo[:, 2]))
    phi_i, phi_o = np.degrees(np.arctan2(wi[:, 1], wi[:, 0])), np.degrees(np.arctan2(wo[:, 1], wo[:, 0]))
    a0, b0, f0 = _rows(0.0)
    rows = [f"{x:.12g},{abs(y):.12g},180,{0 if y >= 0 else 180},{v[0]:.9g},{v[1]:.9g},{v[2]:.9g}"
            for x, y, v in zip(a0, b0, f0, strict=True)]  # the in-plane sweep: the detector at phi 0 or 180
    rows += [f"{x:.12g},{y:.12g},{p:.12g},{q:.12g},{v[0]:.9g},{v[1]:.9g},{v[2]:.9g}"
             for x, y, p, q, v in zip(ti, to, phi_i, phi_o, f, strict=True)]
    (tmp_path / "phi.csv").write_text("theta_i,theta_o,phi_i,phi_o,R,G,B\n" + "\n".join(rows) + "\n")
    tilt_rows = [f"{x:g},{y:g},{t:g},{v[0]:.9g},{v[1]:.9g},{v[2]:.9g}" for t, (aa, bb, ff) in
                 ((0.0, (a0, b0, f0)), (30.0, (a, b, f))) for x, y, v in zip(aa, bb, ff, strict=True)]
    (tmp_path / "tilt.csv").write_text("incidence_deg,outgoing_deg,tilt,R,G,B\n" + "\n".join(tilt_rows) + "\n")
    p = inputs.load_inputs([tmp_path / "phi.csv"], quantity="brdf").slice
    t = inputs.load_inputs([tmp_path / "tilt.csv"], quantity="brdf").slice
    assert isinstance(p, SliceWithPoints) and isinstance(t, SliceWithPoints)
    tilted_p, tilted_t = points_anywhere(p), points_anywhere(t)
    assert tilted_p is not None and tilted_t is not None
    for pts in (tilted_p, tilted_t):  # the tilted rows' directions and values, wherever they came from
        far = np.abs(pts.wi[:, 1]) > 1e-9
        np.testing.assert_allclose(pts.wi[far], wi, atol=1e-9)
        np.testing.assert_allclose(pts.wo[far], wo, atol=1e-9)
        np.testing.assert_allclose(pts.values[far], f, rtol=1e-7)


def test_every_method_reads_the_tilted_points(tmp_path):
    s = inputs.load_inputs([_slice_file(tmp_path / "s.csv", (0.0, 30.0))]).slice
    assert len(everywhere(s)) == 2 * len(s)  # fit, microfacet and prior fit every point
    rec, _ = pipeline.reconstruct(s, "fit", Options())
    assert rec.samples_left_out["left_out"] == 0 and rec.samples_left_out["used"] == 2 * len(s)
    rec, _ = pipeline.reconstruct(s, "revolve", Options())
    assert rec.samples_left_out["left_out"] == len(s)  # in-plane only: says it left the tilted sweep out


@pytest.mark.parametrize("header, row, message", [
    ("theta_i,theta_o,tilt,phi_i,value", "40,10,30,0,0.1", "both a tilt column and azimuth columns"),
    ("theta_i,theta_o,phi_i,value", "40,10,0,0.1", "needs the other"),
    ("theta_i,theta_o,tilt,value", "40,10,95,0.1", "column tilt_deg: 95.0 is outside"),
    ("theta_i,theta_o,phi_i,phi_o,value", "40,-10,180,0,0.1", "polar angles"),
])
def test_bad_direction_columns_name_the_file_and_line(tmp_path, header, row, message):
    p = tmp_path / "t.csv"
    p.write_text(f"{header}\n{row}\n")
    with pytest.raises((inputs.InputError, SliceError), match=message):
        inputs.load_inputs([p], quantity="brdf")
