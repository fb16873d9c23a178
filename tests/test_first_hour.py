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
