"""--prior over several folders (repeated, or joined by os.pathsep): one prior of all their materials, synthetic
material TOML files only."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from reconstruction.base import ReconstructionError
from reconstruction.core.models import Material
from reconstruction.core.slicedata import Slice
from reconstruction.formats.slicefile import write_slice
from reconstruction.methods import prior
from reconstruction.synthetic import synthetic_slice

TARGET = Material.from_dict({"name": "target", "lobes": [
    {"type": "lambert", "albedo": [0.4, 0.25, 0.1]}, {"type": "ggx", "alpha": 0.18, "specular": 0.9, "f0": 0.04}]})


def _write(folder, names_alphas):
    folder.mkdir(parents=True, exist_ok=True)
    for name, (alb, alpha) in names_alphas.items():
        (folder / f"{name}.toml").write_text(
            f'[material]\nname = "{name}"\n[[material.lobes]]\ntype = "lambert"\nalbedo = {alb}\n'
            f'[[material.lobes]]\ntype = "ggx"\nalpha = {alpha}\nspecular = 0.9\nf0 = 0.04\n', encoding="utf-8")
    return folder


@pytest.fixture()
def folders(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    prior._load_cached.cache_clear()
    prior._load_set.cache_clear()
    mats = {f"m{k}": ([round(0.1 + 0.05 * k, 3), 0.2, round(0.5 - 0.04 * k, 3)], round(0.05 + 0.06 * k, 3))
            for k in range(8)}
    names = sorted(mats)
    a = _write(tmp_path / "a", {n: mats[n] for n in names[:3]})
    b = _write(tmp_path / "b", {n: mats[n] for n in names[3:]})
    both = _write(tmp_path / "both", mats)
    yield a, b, both
    prior._load_cached.cache_clear()
    prior._load_set.cache_clear()


def test_several_folders_are_one_prior_of_all_their_materials(folders):
    a, b, both = folders
    whole = prior.load_prior(both)
    for spec in ([a, b], f"{a}{os.pathsep}{b}", (str(a), str(b), str(a))):
        ps = prior.load_prior(spec)
        assert sorted(ps.names) == sorted(whole.names) and len(ps.names) == 8
        order = [whole.names.index(n) for n in ps.names]
        np.testing.assert_array_equal(ps.tables, whole.tables[order])
    assert prior.prior_folders(f"{a}{os.pathsep}{os.pathsep}{b}") == (str(a), str(b))
    # a reconstruction from the two folders is the one from a folder holding all the materials
    s = synthetic_slice(TARGET, (40.0,))
    t_two = prior.reconstruct_prior(s, [a, b]).table()
    t_one = prior.reconstruct_prior(s, both).table()
    np.testing.assert_allclose(t_two, t_one, rtol=1e-5, atol=1e-9)
    # leave-one-out reaches a material of either folder
    rec = prior.reconstruct_prior(s, [a, b], exclude=("m1", "m6"))
    assert rec.report()["prior"]["materials"] == 6


def test_a_material_in_two_folders_and_an_empty_list_are_clear_errors(folders, tmp_path):
    a, b, _ = folders
    c = tmp_path / "c"
    c.mkdir()
    shutil.copy(a / "m0.toml", c / "m0.toml")
    shutil.copy(b / "m5.toml", c / "m5.toml")
    with pytest.raises(ReconstructionError, match="material m0 is also in"):
        prior.load_prior([a, c])
    with pytest.raises(ReconstructionError, match="no folder given"):
        prior.load_prior(os.pathsep)


def test_gonio_reconstruct_takes_prior_repeated_and_joined(folders, tmp_path):
    a, b, _ = folders
    s = synthetic_slice(TARGET, (40.0,))
    src = tmp_path / "slice.csv"
    write_slice(src, Slice(s.theta_i_deg, s.theta_o_deg, s.values, s.channels, 0.002 * s.values + 1e-6,
                           np.full(len(s), 4), 1.795e9 + np.arange(len(s)), meta={"material": "t"}))
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache")}
    for k, args in enumerate((["--prior", str(a), "--prior", str(b)], ["--prior", f"{a}{os.pathsep}{b}"])):
        r = subprocess.run([sys.executable, "-m", "reconstruction.cli", str(src), "--method", "prior", *args,
                            "--out", str(tmp_path / "m.binary"), "--report", str(tmp_path / "m.json")],
                           capture_output=True, text=True, env=env)
        assert r.returncode == 0, r.stderr
        assert json.loads((tmp_path / "m.json").read_text())["details"]["prior"]["materials"] == 8
        # the first run says where each folder's tabulation is cached and how to clear it; the second reads it
        cached = [ln for ln in r.stderr.splitlines() if "cached in" in ln]
        if k == 0:
            assert len(cached) == 2, r.stderr
            for folder, line in zip((a, b), cached, strict=True):
                assert f"materials in {folder}" in line and "delete it to rebuild" in line, line
                path = line.split("cached in ")[1].split(" (")[0]
                assert os.path.isfile(path) and path.startswith(str(tmp_path / "cache")), line
        else:
            assert cached == [], r.stderr


def test_the_prior_build_reports_its_progress(folders):
    from reconstruction.cache import BUILD_PROGRESS

    _, _, both = folders
    seen: list[tuple[str, int, int]] = []
    token = BUILD_PROGRESS.set(lambda what, done, total: seen.append((what, done, total)))
    try:
        prior.load_prior(both)
    finally:
        BUILD_PROGRESS.reset(token)
    assert [d for _, d, _ in seen] == list(range(9)) and {t for *_, t in seen} == {8}
    assert all(str(both) in w for w, *_ in seen)


def test_rgl_files_are_prior_materials(folders, tmp_path):
    """A prior folder may hold RGL .bsdf files (the RGL database's, our --rgl output) beside other materials: each
    is tabulated through formats.brdffile.load_brdf (which reads Zemax files the same way), and the tables agree
    with the same materials given as TOML (within the RGL grid's resolution)."""
    from reconstruction.formats import rgl

    _, _, both = folders
    pick = ["m2", "m5"]
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    for name in pick:
        rgl.write(mixed / f"{name}.bsdf", Material.from_toml(both / f"{name}.toml").eval)
    shutil.copy(both / "m0.toml", mixed / "m0.toml")
    ps = prior.load_prior(mixed)
    assert sorted(ps.names) == ["m0", "m2", "m5"]
    ref = prior.load_prior(both)
    g = prior._grid()
    fc = (g["cos"] * g["within"])[None, g["train"]]  # the tables hold the training cells
    for name in pick:
        got = ps.tables[ps.names.index(name)].astype(np.float64) * fc
        want = ref.tables[ref.names.index(name)].astype(np.float64) * fc
        rel = np.sqrt(np.sum((got - want) ** 2) / np.sum(want ** 2))
        assert rel < 0.05, (name, rel)
