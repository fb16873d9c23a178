"""Scene files (reconstruction.core.scene): parsing, defaults, and errors that name the file and the key."""

import math

import pytest

from reconstruction.base import ReconstructionError
from reconstruction.core.scene import Scene, SceneError, load_scene, scene_from_dict
from reconstruction.schema.scene import LOBE_KINDS


def test_repository_scene_file(repo_root):
    path = repo_root / "configs" / "scenes" / "glossy-product.toml"
    s = load_scene(path)
    assert s == Scene(name="glossy-product", theta_i_deg=(15.0, 45.0), theta_o_deg=(0.0, 75.0),
                      angular_resolution_deg=1.0, lobes=("lambert", "ggx", "fresnel"), relative_rmse=0.03,
                      relative_sigma=None, source=str(path))
    assert isinstance(s.theta_i_deg[0], float)
    for p in (repo_root / "configs" / "scenes").glob("*.toml"):
        assert load_scene(p).name == p.stem


def test_all_keys_optional_and_defaults_explicit(tmp_path):
    p = tmp_path / "studio.toml"
    p.write_text("[scene]\n")
    s = load_scene(p)
    assert s.name == "studio"  # the file name without .toml
    assert s.source == str(p)
    assert s.theta_i_deg is None and s.theta_o_deg is None
    assert s.angular_resolution_deg is s.lobes is s.relative_rmse is s.relative_sigma is None
    assert s.ranges((0.0, 85.0)) == ((0.0, 85.0), (0.0, 85.0))  # each program names its own default
    s = scene_from_dict({"scene": {"theta_o_deg": [10, 20], "error_budget": {"relative_sigma": 1}}}, "x/y.toml")
    assert s.ranges((0.0, 89.999)) == ((0.0, 89.999), (10.0, 20.0))
    assert s.relative_sigma == 1.0 and s.name == "y"
    assert scene_from_dict({"scene": {}}).source == "<scene>"


def test_every_lobe_kind_is_accepted():
    assert scene_from_dict({"scene": {"lobes": list(LOBE_KINDS)}}).lobes == LOBE_KINDS


@pytest.mark.parametrize("text, pattern", [
    ("[scene]\ncolour = 1\n", r"scene\.toml: \[scene\]\.colour: unknown key; allowed keys: name, theta_i_deg"),
    ("[scene]\ncolour = 1\nshade = 2\n", r"\[scene\]\.colour: unknown key \(and shade\)"),
    ("[scene]\n[other]\n", r"scene\.toml: \[other\]: unknown section"),
    ("name = 'x'\n", r"scene\.toml: no \[scene\] table"),
    ("scene = 1\n", r"no \[scene\] table"),
    ("[scene]\nname = 3\n", r"\[scene\]\.name: expected a string, got 3"),
    ("[scene]\ntheta_i_deg = [50, 10]\n", r"scene\.toml: \[scene\]\.theta_i_deg: expected \[min, max\]"),
    ("[scene]\ntheta_o_deg = [10, 90]\n", r"\[scene\]\.theta_o_deg: expected \[min, max\]"),
    ("[scene]\ntheta_o_deg = [true, 10]\n", r"\[scene\]\.theta_o_deg: expected \[min, max\]"),
    ("[scene]\ntheta_o_deg = [1, 2, 3]\n", r"\[scene\]\.theta_o_deg: expected \[min, max\]"),
    ("[scene]\nlobes = ['phong']\n", r"scene\.toml: \[scene\]\.lobes: expected a list of lambert"),
    ("[scene]\nlobes = []\n", r"\[scene\]\.lobes"),
    ("[scene]\nlobes = 'ggx'\n", r"\[scene\]\.lobes"),
    ("[scene]\nangular_resolution_deg = 'fine'\n", r"\[scene\]\.angular_resolution_deg: expected a positive"),
    ("[scene]\nangular_resolution_deg = 0\n", r"\[scene\]\.angular_resolution_deg: expected a positive"),
    ("[scene]\nangular_resolution_deg = true\n", r"\[scene\]\.angular_resolution_deg: expected a positive"),
    ("[scene]\nangular_resolution_deg = inf\n", r"\[scene\]\.angular_resolution_deg: expected a positive"),
    ("[scene.error_budget]\nrelative_rmse = -1\n",
     r"scene\.toml: \[scene\.error_budget\]\.relative_rmse: expected a positive number"),
    ("[scene]\nerror_budget = 0.1\n", r"\[scene\.error_budget\]: expected a table"),
    ("[scene.error_budget]\nrmse = 0.1\n", r"\[scene\.error_budget\]\.rmse: unknown key; allowed keys: "
                                           r"relative_rmse, relative_sigma"),
    ("[scene\n", r"scene\.toml: invalid TOML"),
    ("[scene.view]\ngeometry = 'cube'\nlights_deg = [[0, 0]]\n", r"\[scene\.view\]\.geometry: expected one of sphere"),
    ("[scene.view]\ngeometry = 'sphere'\n", r"\[scene\.view\]\.lights_deg: missing"),
    ("[scene.view]\nlights_deg = [45]\n", r"\[scene\.view\]\.lights_deg: expected a list of \[polar, azimuth\]"),
    ("[scene.view]\ngeometry = 'plane'\nlights_deg = [[30, 180]]\n", r"\[scene\.view\]\.camera_deg: missing"),
    ("[scene.view]\ngeometry = 'plane'\ncamera_deg = [95]\nlights_deg = [[30, 180]]\n",
     r"\[scene\.view\]\.camera_deg: expected a list of polar angles"),
    ("[scene.view]\ngeometry = 'plane'\ncamera_deg = [0]\nlights_deg = [[120, 0]]\n", r"a plane's lights are above it"),
    ("[scene.view]\nlights_deg = [[40, 0]]\ncoverage = 0\n", r"\[scene\.view\]\.coverage: expected a share"),
    ("[scene.view]\nlights_deg = [[40, 0]]\nzoom = 2\n", r"\[scene\.view\]\.zoom: unknown key; allowed keys: geometry"),
    ("[scene]\nview = 3\n", r"\[scene\.view\]: expected a table"),
])
def test_bad_scene_files(tmp_path, text, pattern):
    p = tmp_path / "scene.toml"
    p.write_text(text)
    with pytest.raises(SceneError, match=pattern):
        load_scene(p)


def test_errors_are_value_errors_and_name_missing_files(tmp_path):
    assert issubclass(SceneError, ReconstructionError) and issubclass(SceneError, ValueError)
    with pytest.raises(SceneError, match=r"none\.toml: no such scene file"):
        load_scene(tmp_path / "none.toml")
    (tmp_path / "bin.toml").write_bytes(b"\xff\xfe[scene]\n")
    with pytest.raises(SceneError, match=r"bin\.toml: invalid TOML"):
        load_scene(tmp_path / "bin.toml")
    with pytest.raises(SceneError, match=r"<scene>: \[scene\]\.relative_rmse: unknown key"):
        scene_from_dict({"scene": {"relative_rmse": math.pi}})


def test_a_view_gives_the_ranges_a_renderer_uses():
    """[scene.view]: a key light near the camera sees a sphere at moderate angles, a rim light behind it only at
    grazing ones; a plane's ranges are its cameras' and lights' angles; ranges the file gives win."""
    key = scene_from_dict({"scene": {"view": {"lights_deg": [[30.0, 0.0]]}}})
    rim = scene_from_dict({"scene": {"view": {"lights_deg": [[150.0, 0.0]]}}})
    assert key.theta_i_deg[0] < 20.0 and 55.0 < key.theta_i_deg[1] < 85.0
    assert rim.theta_i_deg[0] > 55.0 and rim.theta_o_deg[0] > 55.0 and rim.theta_o_deg[1] < 90.0
    assert "sphere" in rim.view and "theta_i_deg" in rim.view
    wide = scene_from_dict({"scene": {"view": {"lights_deg": [[30.0, 0.0]], "coverage": 1.0}}})
    assert wide.theta_i_deg[0] <= key.theta_i_deg[0] and wide.theta_i_deg[1] >= key.theta_i_deg[1]
    plane = scene_from_dict({"scene": {"view": {"geometry": "plane", "camera_deg": [20.0, 60.0],
                                                "lights_deg": [[45.0, 180.0], [10.0, 90.0]]}}})
    assert plane.theta_i_deg == (10.0, 45.0) and plane.theta_o_deg == (20.0, 60.0)
    given = scene_from_dict({"scene": {"theta_o_deg": [0.0, 30.0], "view": {"lights_deg": [[150.0, 0.0]]}}})
    assert given.theta_o_deg == (0.0, 30.0) and given.theta_i_deg == rim.theta_i_deg
    with pytest.raises(SceneError, match="no light reaches"):
        scene_from_dict({"scene": {"view": {"lights_deg": [[180.0, 0.0]]}}})
