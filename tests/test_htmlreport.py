"""gonio-reconstruct --html: one self-contained page per material, and a batch index."""

import base64
import json
import re
from html.parser import HTMLParser

import numpy as np

from reconstruction import cli
from reconstruction.htmlreport import SECTIONS
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


def test_html_report_is_self_contained_and_matches_the_json_report(tmp_path):
    src = slice_file(tmp_path / "slice.csv", BLUE_PLASTIC, incidences=(20.0, 50.0))
    html_path, report = tmp_path / "m.html", tmp_path / "m.json"
    assert cli.main([str(src), "--out", str(tmp_path / "m.binary"), "--report", str(report), "--html",
                     str(html_path), "--quiet"]) == 0
    page = parse(html_path)
    assert page.sections == list(SECTIONS)
    assert not [x for x in page.links if re.match(r"https?:", x or "")]  # nothing fetched from the network
    assert len(page.images) == 6  # slices, polar, coverage, spheres, cuts, albedo
    for src_uri in page.images:  # every image is inline and decodes as a PNG
        head, data = src_uri.split(",", 1)
        assert head == "data:image/png;base64"
        png = base64.b64decode(data)
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 2000
    rep = json.loads(report.read_text())
    text = " ".join(page.text)
    assert rep["method"] in text and rep["method_reason"] in text
    for c in rep["cross_validation"]["scores"]:  # every method's held-out error, as in the JSON
        assert c["method"] in text and f"{c['held_out_relative_rmse_cos']:.4%}" in text
    assert "Checks passed." in text
    alpha = next(p for p in rep["parameters"] if p["type"] == "ggx")["alpha"]
    assert f"{alpha:.6g}" in text
    assert rep["outputs"]["html"] == str(html_path)


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
