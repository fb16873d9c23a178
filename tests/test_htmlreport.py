"""gonio-reconstruct --html: one self-contained page per material, and a batch index."""

import base64
import json
import re
from html.parser import HTMLParser

import numpy as np
import pytest

from reconstruction import cli
from reconstruction.report.html import SECTIONS
from tests.test_cli_reconstruct import BLUE_PLASTIC, slice_file


class Page(HTMLParser):
    def __init__(self):
        super().__init__()
        self.sections, self.images, self.links, self.text = [], [], [], []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "section":
            self.sections.append(a.get("id"))
        if tag == "img":
            self.images.append(a["src"])
        if tag in ("a", "link", "script") and (a.get("href") or a.get("src")):
            self.links.append(a.get("href") or a.get("src"))

    def handle_data(self, data):
        self.text.append(data)


def parse(path):
    p = Page()
    p.feed(path.read_text(encoding="utf-8"))
    return p


@pytest.mark.slow
def test_html_report_is_self_contained_and_matches_the_json_report(tmp_path):
    src = slice_file(tmp_path / "slice.csv", BLUE_PLASTIC, incidences=(20.0, 50.0))
    html_path, report = tmp_path / "m.html", tmp_path / "m.json"
    assert cli.main([str(src), "--out", str(tmp_path / "m.binary"), "--report", str(report), "--html",
                     str(html_path), "--quiet"]) == 0
    page = parse(html_path)
    assert page.sections == list(SECTIONS)
    assert not [x for x in page.links if re.match(r"https?:", x or "")]  # nothing fetched from the network
    assert len(page.images) == 12  # slices, polar, coverage, sigma, cuts, albedo and the six spheres
    for src_uri in page.images:  # every image is inline and decodes as a PNG
        head, data = src_uri.split(",", 1)
        assert head == "data:image/png;base64"
        png = base64.b64decode(data)
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 2000
    spheres = [base64.b64decode(u.split(",", 1)[1]) for u in page.images[4:10]]  # after coverage and sigma
    assert {int.from_bytes(p[16:20], "big") for p in spheres} == {112}  # the renders' own pixels (PNG width)
    rep = json.loads(report.read_text())
    text = " ".join(page.text)
    for caption in ("point light, upper left", "environment + rim sun (behind)"):
        assert caption in text
    assert rep["method"] in text and rep["method_reason"] in text
    for c in rep["cross_validation"]["scores"]:  # every method's held-out error, as in the JSON
        assert c["method"] in text and f"{c['held_out_relative_rmse_cos']:.4%}" in text
        assert f"{c['held_out_image_error']:.4f}" in text  # the image error auto ranks by
    assert "held-out image error" in text
    assert "Checks passed." in text
    alpha = next(p for p in rep["parameters"] if p["type"] == "ggx")["alpha"]
    assert f"{alpha:.6g}" in text
    assert rep["outputs"]["html"] == str(html_path)


@pytest.mark.slow
def test_batch_html_writes_a_page_per_material_and_an_index(tmp_path):
    d = tmp_path / "captures"
    d.mkdir()
    slice_file(d / "a.csv", BLUE_PLASTIC)
    slice_file(d / "b.csv", BLUE_PLASTIC, incidences=(40.0,))
    (d / "broken.csv").write_text("theta_i_deg,theta_o_deg\n1,2\n")
    out = tmp_path / "materials"
    code = cli.main(["--batch", str(d), "--out-dir", str(out), "--html", "--quiet", "--workers", "1",
                     "--method", "bivariate"])
    assert code == 1  # one file is broken
    for name in ("a", "b"):
        assert parse(out / f"{name}.html").sections == list(SECTIONS)
    index = parse(out / "index.html")
    assert {"a.html", "b.html"} <= set(index.links)
    assert any("broken" in t for t in index.text)


def test_html_needs_a_file_name_outside_batch(tmp_path, capsys):
    src = slice_file(tmp_path / "slice.csv", BLUE_PLASTIC)
    assert cli.main([str(src), "--out", str(tmp_path / "m.binary"), "--html"]) == 2
    assert "--html" in capsys.readouterr().err
    assert not (tmp_path / "m.binary").exists()
    assert cli.main([str(src), "--out", str(tmp_path / "m.binary"), "--html", str(tmp_path / "m.txt")]) == 2
    assert np.all([not (tmp_path / f).exists() for f in ("m.binary", "m.txt")])


# --- the figures: the environment sphere, the coverage legend, the albedo of grey data ---------------------------


@pytest.mark.slow
def test_the_environment_sphere_is_the_integral_of_the_environment_at_the_rim_too():
    """The page's sky-and-ground sphere (a glossy lobe, GGX alpha 0.05): each pixel, the grazing views at the rim
    included, is the environment's integral (the old render summed 192 fixed world directions, so a glossy lobe
    at grazing views met one or none of them: blotches of several times the right value)."""
    from reconstruction.core.models import Material
    from reconstruction.core.render import SkyGround, sphere_coverage
    from reconstruction.report.spheres import _backdrop, environment_render
    from tests.test_render import brute_force

    mat = Material.from_dict({"name": "m", "lobes": [{"type": "lambert", "albedo": 0.1},
                                                      {"type": "ggx", "alpha": 0.05, "specular": 0.9, "f0": 0.04}]})
    size, radius = 112, 0.8
    img = environment_render(mat.eval, size, radius)
    assert img.shape == (size, size, 3)
    cover, back = sphere_coverage(size, radius, antialias=True), _backdrop(size, radius, SkyGround())
    assert np.any((cover > 0) & (cover < 1))  # the edge is anti-aliased
    for view_deg, azimuth_deg in [(0, 0), (60, 30), (75, 200), (82, 120), (84, 300), (85, 170)]:
        r = np.sin(np.radians(view_deg)) * radius * size / 2  # pixels from the centre
        col = int(size / 2 + r * np.cos(np.radians(azimuth_deg)))
        row = int(size / 2 - r * np.sin(np.radians(azimuth_deg)))
        x = ((col + 0.5) / size * 2 - 1) / radius
        y = -((row + 0.5) / size * 2 - 1) / radius
        n = np.array([x, y, np.sqrt(1 - x * x - y * y)])
        ref = brute_force(mat.eval, SkyGround(), n, 600, 1200)[0]
        sphere = (img[row, col, 0] - back[row, col, 0]) / cover[row, col]  # the edge pixels are anti-aliased
        assert abs(sphere / ref - 1) < 0.04, (row, col, np.degrees(np.arccos(n[2])))


def test_the_coverage_legend_marker_shows_on_its_frame():
    from matplotlib.colors import to_rgb

    from reconstruction.core import merltable
    from reconstruction.core.slicedata import Slice
    from reconstruction.report.html import _coverage_plot

    s = Slice(np.array([30.0, 30.0]), np.array([-20.0, 40.0]), np.array([[0.1], [0.3]]), ["value"])
    table = np.full(merltable.SHAPE, 0.1)
    fig = _coverage_plot(table, s)
    leg = fig.axes[0].get_legend()
    frame = np.array(to_rgb(leg.get_frame().get_facecolor()))
    handle = leg.legend_handles[0]
    assert leg.texts[0].get_text() == "measured samples"
    colours = [np.array(to_rgb(c)) for c in (handle.get_markerfacecolor(), handle.get_markeredgecolor())]
    assert max(np.abs(c - frame).max() for c in colours) > 0.3  # one of them stands out from the frame
    assert handle.get_markersize() * leg.markerscale >= 4


def test_grey_data_have_one_albedo_curve():
    from reconstruction.report.html import _albedo_plot

    ti = [0.0, 30.0, 60.0]
    grey = {"albedo": {"theta_i_deg": ti, "albedo": [[0.2, 0.2, 0.2], [0.21, 0.21, 0.21], [0.3, 0.3, 0.3]]}}
    colour = {"albedo": {"theta_i_deg": ti, "albedo": [[0.1, 0.2, 0.3], [0.1, 0.2, 0.3], [0.2, 0.3, 0.4]]}}

    def curves(checks):
        ax = _albedo_plot(checks).axes[0]
        return [ln.get_label() for ln in ax.get_lines() if not ln.get_label().startswith("limit")]

    assert curves(grey) == ["grey (every channel)"]
    assert curves(colour) == ["R", "G", "B"]


@pytest.mark.slow
def test_an_html_report_a_preview_or_a_report_alone_is_an_output(tmp_path, capsys):
    """--out is optional once another output is asked: the HTML page (or the preview, or the JSON report) alone
    is written, and no table."""
    src = slice_file(tmp_path / "slice.csv", BLUE_PLASTIC, step=4.0)
    assert cli.main([str(src), "--html", str(tmp_path / "r.html"), "--quiet"]) == 0
    assert parse(tmp_path / "r.html").sections == list(SECTIONS)
    assert cli.main([str(src), "--preview", str(tmp_path / "p.exr"), "--report", str(tmp_path / "p.json")]) == 0
    assert (tmp_path / "p.exr").exists() and (tmp_path / "p.png").exists()
    rep = json.loads((tmp_path / "p.json").read_text())
    assert "table" not in rep["outputs"] and rep["outputs"]["preview"]["exr"] == str(tmp_path / "p.exr")
    assert "wrote " + str(tmp_path / "p.exr") in capsys.readouterr().err
    assert not list(tmp_path.glob("*.binary"))
    # nothing asked: still one line pointing at the flags
    with pytest.raises(SystemExit) as e:
        cli.main([str(src)])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "--out MATERIAL.binary or another output (--preview, --html" in err


def test_the_help_of_out_names_every_other_output():
    from reconstruction.formats.exports import OTHER_OUTPUTS

    out = next(a for a in cli.build_parser()._actions if "--out" in a.option_strings)
    assert "optional once another output is asked" in out.help
    for flag in OTHER_OUTPUTS:
        assert "--" + flag.replace("_", "-") in out.help, flag


def test_a_hemispherical_file_draws_at_most_eight_incidences_spread_over_its_range():
    """Per-incidence figures of a file with dozens of incidences (a Zemax file's 26) draw MAX_PANELS of them, the
    first and the last included, 4 a row, and the page's note says which; a few slices are all drawn."""
    from reconstruction.core.slicedata import Slice
    from reconstruction.report import html

    inc = np.concatenate([np.arange(0.0, 50.0, 5.0), np.arange(50.0, 88.0, 2.5)])  # 26 incidences
    ti = np.repeat(inc, 3)
    s = Slice(ti, np.tile([-30.0, 0.0, 30.0], inc.size), np.full((ti.size, 1), 0.1), ["value"])
    shown = html.shown_incidences(s)
    assert len(shown) == html.MAX_PANELS and shown[0] == 0.0 and shown[-1] == 87.5
    assert shown == sorted(set(shown)) and set(shown) <= set(inc.tolist())
    assert f"{html.MAX_PANELS} of the 26 incidences are drawn" in html._shown_note(s)
    few = s.take(np.isin(s.theta_i_deg, [20.0, 40.0, 60.0]))
    assert html.shown_incidences(few) == [20.0, 40.0, 60.0] and html._shown_note(few) == ""
    fig, axes = html._panels(len(shown), 5.2, 3.8)
    assert len(axes) == len(shown) and fig.axes[0].get_gridspec().ncols == html.PANELS_PER_ROW


# --- the drawer: figures drawn in a forked child as their data arrive -------------------------------------------


def _square(n):
    return f"data:{n * n}"


def _fails(n):
    raise ValueError(f"no figure of {n}")


def _pid(_):
    import os

    return f"data:{os.getpid()}"


def test_the_drawer_draws_in_a_child_and_keeps_the_last_of_a_name():
    import os

    from reconstruction.report.figures import Drawer, can_fork

    with Drawer() as d:
        d.draw("a", _square, 3)
        d.draw("who", _pid, None)
        d.draw("a", _square, 4)  # sent again (its data changed): the last one kept
        got = d.results()
    assert got["a"] == "data:16"
    assert (got["who"] != f"data:{os.getpid()}") == can_fork()  # drawn by the child where there is one
    with Drawer(enabled=False) as d:  # no child: drawn here when asked
        d.draw("who", _pid, None)
        assert d.results() == {"who": f"data:{os.getpid()}"}


def test_a_figure_that_fails_in_the_child_raises_here_and_an_unused_drawer_leaves_no_child():
    import os

    from reconstruction.report.figures import Drawer

    with Drawer() as d:
        d.draw("ok", _square, 2)
        d.draw("bad", _fails, 7)
        with pytest.raises(ValueError, match="no figure of 7"):
            d.results()
    with Drawer() as d:
        pid = d._pid
        d.draw("ok", _square, 2)
    if pid:  # left without asking: the child was ended and reaped
        with pytest.raises(ChildProcessError):
            os.waitpid(pid, os.WNOHANG)


def test_a_log_axis_over_decades_draws_its_minor_grid_as_one_collection():
    """figures.log_grid: a log axis spanning two decades or more gets no minor ticks and its minor grid lines (2..9
    x 10^k within the limits) as one line collection; a narrower axis keeps matplotlib's minor ticks."""
    from matplotlib.collections import LineCollection

    from reconstruction.report.figures import figure, log_grid

    fig = figure((4, 3))
    wide, narrow = fig.subplots(1, 2)
    for ax, top in ((wide, 1e3), (narrow, 5.0)):
        ax.plot([0, 1], [1.0, top])
        ax.set_yscale("log")
        log_grid(ax)
    lo, hi = wide.get_ylim()
    lines = [c for c in wide.collections if isinstance(c, LineCollection)]
    assert len(lines) == 1 and len(wide.yaxis.get_minorticklocs()) == 0
    ys = sorted(seg[0][1] for seg in lines[0].get_segments())
    expected = [m * 10.0 ** k for k in range(-2, 5) for m in range(2, 10) if lo < m * 10.0 ** k < hi]
    np.testing.assert_allclose(ys, expected)
    assert not narrow.collections and len(narrow.yaxis.get_minorticklocs()) > 0


def test_the_sigma_map_is_the_median_over_phi_d_of_the_cells_above_the_horizon():
    from reconstruction.core import merlgrid, merltable
    from reconstruction.report.html import sigma_values

    rng = np.random.default_rng(2)
    sigma = rng.uniform(0.01, 2.0, merltable.SHAPE).astype(np.float32)
    sigma[0, 10, 20, :7] = np.nan  # a few cells without a value: left out as below the horizon
    sg = np.where(merlgrid.valid_mask(), sigma.astype(np.float64).mean(axis=0), np.nan)
    with np.errstate(all="ignore"), __import__("warnings").catch_warnings():
        __import__("warnings").simplefilter("ignore", RuntimeWarning)
        expected = np.nanmedian(sg, axis=2)
    np.testing.assert_allclose(sigma_values(sigma), expected, rtol=1e-6, equal_nan=True)
    assert np.isnan(sigma_values(sigma)[89, 89])  # no cell of that row above the horizon


def test_background_work_without_a_second_thread_runs_once_when_first_asked():
    from reconstruction.executor import Background

    calls = []
    with Background(enabled=False) as bg:
        result = bg.submit(lambda x: calls.append(x) or x * 2, 21)
        assert calls == []  # nothing until asked
        assert result() == 42 and result() == 42 and calls == [21]


def test_the_page_reuses_the_other_methods_when_only_the_bound_changed_the_reconstruction(monkeypatch):
    """pipeline._send_sample_figures builds every other method once; the bound (same method) reuses them, a
    fallback to one of them builds them again."""
    from types import SimpleNamespace

    from reconstruction import pipeline
    from reconstruction.core.slicedata import Slice
    from reconstruction.job import Job
    from reconstruction.report import html as htmlreport

    built = []
    monkeypatch.setattr(pipeline, "_other_methods",
                        lambda w, r, o, b=None: built.append(r.method) or {"x": r, "y": r})
    monkeypatch.setattr(htmlreport, "draw_sample_figures", lambda *a, **k: None)
    s = Slice(np.array([30.0, 30.0]), np.array([-20.0, 40.0]), np.array([[0.1], [0.3]]), ["value"])
    job = Job(inputs=("s.csv",), out=None, html="m.html")
    others = pipeline._send_sample_figures(job, None, s, SimpleNamespace(method="fit"), {}, None)
    assert built == ["fit"]
    bounded = SimpleNamespace(method="fit")  # the bound: the same method, another reconstruction
    assert pipeline._send_sample_figures(job, None, s, bounded, {}, None, others) is others and built == ["fit"]
    pipeline._send_sample_figures(job, None, s, SimpleNamespace(method="x"), {}, None, others)  # a fallback
    assert built == ["fit", "x"]
