"""The small things a new user met in the first hour (issue 41, item 13), each as it must read now."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
CLIS = {"gonio-capture": "acquisition.cli", "gonio-reconstruct": "reconstruction.cli", "gonio-sim": "simulator.cli",
        "gonio-compare": "reconstruction.report.compare"}


def readme_headings() -> set[str]:
    text = re.sub(r"```.*?```", "", README, flags=re.S)
    return {re.sub(r"[`*]", "", m.group(1)).strip().lower() for m in re.finditer(r"^#{1,6} (.+)$", text, flags=re.M)}


def help_text(module: str) -> str:
    parser = importlib.import_module(module).build_parser()
    texts = [parser.format_help()]
    for action in parser._actions:  # sub-commands' help (gonio-sim serve, check, bench)
        choices = getattr(action, "choices", None)
        if isinstance(choices, dict):
            texts += [sub.format_help() for sub in choices.values()]
    return "\n".join(texts)


@pytest.mark.parametrize("name", sorted(CLIS))
def test_help_points_to_what_exists_and_reads_plain(name):
    """``--help`` names README sections that exist and docs pages that exist, and shows no raw reST."""
    text = help_text(CLIS[name])
    for section in re.findall(r"README[:,] ([A-Z][\w ,-]*?)[)\n;]", text):
        assert section.strip().lower() in readme_headings(), f"{name} --help points to README section {section!r}"
    for page in re.findall(r"docs/[\w./-]+\.md", text):
        assert (ROOT / page).exists(), f"{name} --help points to {page}, which does not exist"
    raw = re.findall(r"``[^`]+``|:(?:func|class|mod|meth|data):`", text)
    assert not raw, f"{name} --help shows raw reST: {raw[:5]}"


def test_a_pareto_front_of_one_point_is_drawn():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from simulator.study import draw_front

    fig, ax = plt.subplots()
    line = draw_front(ax, [{"capture_time_s": 7.2, "rel_rmse_cos": 0.0008}])
    assert line.get_marker() not in (None, "", "None", " ") and line.get_markersize() > 0
    assert list(line.get_xdata()) == [7.2]
    plt.close(fig)


def test_check_groups_the_unmeasurable_points(capsys):
    """configs/dynamixel-bench.toml's 68 unmeasurable points: one line per incidence and reason, not 68."""
    from acquisition.cli import main

    assert main(["--config", str(ROOT / "configs" / "dynamixel-bench.toml"), "--check"]) == 0
    out = capsys.readouterr().out
    head, *rest = out.split("\n")
    assert head == "576 measurable points, 68 not measurable", head
    listed = [ln for ln in rest if ln.startswith("  ")]
    assert listed == [f"  theta_i {ti}, theta_o {-ti - 8} to {-ti + 8} (17 points): collision: arms closer than "
                      "min_separation_deg 8 (at the goals sent)" for ti in (15, 30, 45, 60)]


def test_a_point_at_the_separation_limit_says_where_the_servos_put_it():
    """45 and -37 deg are 8 deg apart as planned; the servos' whole units put them 7.998 apart: the reason says
    both, instead of a bare '7.998 deg apart' for whole-degree angles."""
    from acquisition import Bench

    g = Bench.from_config(ROOT / "configs" / "dynamixel-bench.toml").geometry
    assert g.reason(45, -37) == ("collision: arms 8 deg apart (7.998 at the goals sent, in whole servo units), "
                                 "closer than min_separation_deg 8")
    assert g.reason(30, -30) == "collision: arms 0 deg apart, closer than min_separation_deg 8"


def test_a_lone_unmeasurable_point_keeps_its_own_reason():
    from acquisition.plans.plan import group_unmeasurable

    lines = group_unmeasurable([(30.0, -30.0, "collision: arms 0 deg apart, closer than min_separation_deg 6"),
                                (30.0, -20.0, "collision: arms 10 deg apart, closer than min_separation_deg 12")],
                               [(30.0, -25.0)])
    assert lines == ["(30, -30): collision: arms 0 deg apart, closer than min_separation_deg 6",
                     "(30, -20): collision: arms 10 deg apart, closer than min_separation_deg 12"]


def test_check_with_a_scene_says_what_the_scene_changed(capsys):
    """glossy-product keeps 2 of the demo's 3 incidences and grows the plan from 243 to 302 points: --check says
    why (the scene's 1 deg resolution against the plan's 2 deg step) instead of leaving 'restricts' to explain it."""
    from acquisition.cli import main

    argv = ["--config", str(ROOT / "configs" / "simulated.toml"), "--check", "--scene",
            str(ROOT / "configs" / "scenes" / "glossy-product.toml")]
    assert main(argv) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert first == ("scene 'glossy-product': incidences 20, 40 of 20, 40, 60; theta_o -75 to 75; step 1 deg, "
                     "finer than the plan's 2 (the scene's angular_resolution_deg): it adds points: 302 points, "
                     "more than the plan's 243"), first


def test_gonio_sim_check_says_the_config_is_fine():
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "simulator.cli", "check", "--config", "configs/simulated.toml"],
                       cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and len(r.stdout.splitlines()) == 1 and "ready to serve" in r.stdout, r.stdout


def test_a_config_error_is_one_line(tmp_path, capsys):
    """The README promises one line naming the file, the key and what was expected."""
    from acquisition.cli import main

    bad = tmp_path / "bad.toml"
    bad.write_text((ROOT / "configs" / "simulated.toml").read_text(encoding="utf-8").replace(
        "settle_s = 0.05 ", 'settle_s = "x" ', 1), encoding="utf-8")
    assert main(["--config", str(bad), "--check"]) == 2
    err = capsys.readouterr().err
    assert err == f'gonio-capture: {bad}: [motion].settle_s: expected a number, got "x"; nothing was moved\n', err


@pytest.mark.slow
def test_the_html_page_is_titled_by_the_material_and_explains_its_expected_error(tmp_path):
    """The page of examples/data/captures/glossy-red.csv written as m.html: titled 'glossy-red' (the slice's
    material), not 'm'; its expected errors against the truth come with the sentence that sets them beside the
    far smaller held-out error."""
    from reconstruction.cli import main

    src = ROOT / "examples" / "data" / "captures" / "glossy-red.csv"
    assert main([str(src), "--method", "fit", "--html", str(tmp_path / "m.html"), "--uncertainty",
                 str(tmp_path / "m-sigma.npy"), "--quiet"]) == 0
    page = (tmp_path / "m.html").read_text(encoding="utf-8")
    assert "<title>glossy-red: gonio-brdf report</title>" in page and "<h1>glossy-red</h1>" in page
    assert "Expected against the truth" in page and "held-out error" in page and "usually far smaller" in page


def test_the_expected_errors_sentence_quotes_the_held_out_error():
    from reconstruction.report.html import _expected_vs_held_out

    text = _expected_vs_held_out({"cross_validation": {"chosen": "fit", "chosen_label": "fit", "scores": [
        {"method": "fit", "label": "fit", "held_out_relative_rmse_cos": 0.0133}]}})
    assert "(here 1.33% for fit)" in text and "out of the plane" in text
