"""One schema per file format: the shipped files fit their schemas, docs/schema/*.json is generated from them and up
to date, and the bench file's errors keep naming the file, the key path and what was expected."""

from __future__ import annotations

import subprocess
import sys

import msgspec
import pytest

from reconstruction.schema import SchemaError, Table
from reconstruction.schema.bench import BenchFile, MotionTable
from reconstruction.schema.material import MaterialFile
from reconstruction.schema.scene import SceneFile
from tests.test_acq_support import REPO

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


@pytest.mark.parametrize("name", ["simulated.toml", "dynamixel-bench.toml", "serial-bench.toml"])
def test_shipped_files_fit_their_schemas(name):
    raw = tomllib.loads((REPO / "configs" / name).read_text())
    cfg = msgspec.convert(raw, BenchFile)
    assert cfg.bench.transport in ("simulated", "dynamixel", "serial")
    if cfg.material is not None:
        assert msgspec.convert(cfg.material, MaterialFile).lobes
    for scene in sorted((REPO / "configs" / "scenes").glob("*.toml")):
        msgspec.convert(tomllib.loads(scene.read_text()), SceneFile)


def test_json_schemas_are_generated_and_up_to_date():
    r = subprocess.run([sys.executable, str(REPO / "scripts" / "write_schemas.py"), "--check"], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0, r.stderr


def test_a_table_read_against_its_schema_names_the_key_and_the_expectation():
    with pytest.raises(SchemaError, match=r"^f\.toml: \[motion\]\.tolerance: unknown key; did you mean "
                                          r"'tolerance_deg'\?$"):
        Table("f.toml", "motion", {"tolerance": 0.1}, MotionTable)
    with pytest.raises(SchemaError, match=r"^f\.toml: \[motion\]\.retries: must lie in \[0, 100\], got -1$"):
        Table("f.toml", "motion", {"tolerance_deg": 0.1, "settle_s": 0.1, "retries": -1}, MotionTable)
    t = Table("f.toml", "motion", {"tolerance_deg": 0.1, "settle_s": 0.1, "profile_velocity": 50.0}, MotionTable)
    assert t["profile_velocity"] == 50 and isinstance(t["profile_velocity"], int) and t["retries"] == 3
