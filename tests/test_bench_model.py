"""The bench file is modelled once (issue 51): the msgspec structs of :mod:`reconstruction.schema.bench` and
:mod:`reconstruction.schema.simulator` are what ``gonio-capture`` and ``gonio-sim`` read it into. A class in
acquisition or the simulator that declares the keys of one of its tables again (a dataclass, a struct, a named
tuple: a second model of the same table) fails here, and so does a view that redeclares a field of the struct it
extends."""

from __future__ import annotations

import ast
from pathlib import Path

import msgspec.inspect as mi

from reconstruction.schema.bench import BenchFile

REPO = Path(__file__).resolve().parents[1]
#: A class declaring this many keys of one table is a second model of that table.
MIRROR = 3
#: Tables whose keys are tables: a class holding the sections is not a copy of them.
CONTAINERS = {"BenchFile", "AxesTables"}
#: Run-time objects that share names with a table but are not a model of the file, each with why.
NOT_MODELS = {
    "acquisition/calibration.py: Calibration": "a capture's calibration: its readings and factors",
    "acquisition/plans/plan.py: Plan": "a capture plan (sweeps, points), built from [plan] or by code (Plan.grid)",
    "acquisition/plans/generators.py: PlanSpec": "the protocol of Plan",
    "simulator/world/physics.py: Detector": "the virtual detector's state, which the serial protocol changes",
}


def bench_file_tables() -> dict[str, set[str]]:
    """Every table of the bench file (struct name -> its keys), from :class:`BenchFile` down."""
    out: dict[str, set[str]] = {}

    def walk(t: object) -> None:
        if isinstance(t, mi.StructType):
            if t.cls.__name__ in out:
                return
            out[t.cls.__name__] = {f.name for f in t.fields}
            for f in t.fields:
                walk(f.type)
        elif isinstance(t, mi.Metadata):
            walk(t.type)
        elif isinstance(t, (mi.UnionType,)):
            for x in t.types:
                walk(x)
        elif isinstance(t, (mi.ListType, mi.VarTupleType, mi.DictType)):
            walk(getattr(t, "item_type", None) or getattr(t, "value_type", None))

    walk(mi.type_info(BenchFile))
    return out


def _declared(cls: ast.ClassDef) -> list[str]:
    """The names a class body declares as fields (annotated assignments)."""
    return [n.target.id for n in cls.body if isinstance(n, ast.AnnAssign) and isinstance(n.target, ast.Name)]


def _base_names(cls: ast.ClassDef) -> list[str]:
    return [b.id if isinstance(b, ast.Name) else b.attr if isinstance(b, ast.Attribute) else "" for b in cls.bases]


def second_models(source: str, where: str, tables: dict[str, set[str]],
                  views: dict[str, set[str]], schema: bool = False) -> list[str]:
    """What in ``source`` declares a bench-file table again: a class declaring :data:`MIRROR` or more keys of one
    table, or a subclass of a table (or of a view, ``views``: name -> its fields) redeclaring one of its fields.
    ``schema``: the schema's own module (where the tables are declared: only the second check)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.ClassDef) or f"{where}: {node.name}" in NOT_MODELS:
            continue
        own = set(_declared(node))
        for base in _base_names(node):
            inherited = tables.get(base, set()) | views.get(base, set())
            if own & inherited:
                found.append(f"{where}: {node.name} redeclares {sorted(own & inherited)} of {base}")
        for table, keys in tables.items():
            if schema or table in CONTAINERS:
                continue
            if len(own & keys) >= MIRROR:
                found.append(f"{where}: {node.name} declares {sorted(own & keys)}, keys of {table}")
    return found


def _views() -> dict[str, set[str]]:
    from reconstruction.schema.bench import Axis, Detector

    return {c.__name__: set(c.__struct_fields__) for c in (Axis, Detector)}


def test_no_bench_file_key_is_declared_twice():
    tables = bench_file_tables()
    assert {"BenchTable", "AxisTable", "MotionTable", "GrblTable", "DetectorTable", "CalibrationTable", "PlanTable",
            "AdaptiveTable", "SimulatorSection", "FaultsSection"} <= set(tables)
    files = sorted([*REPO.glob("acquisition/**/*.py"), *REPO.glob("simulator/**/*.py"),
                    REPO / "reconstruction" / "schema" / "bench.py"])
    found = [f for p in files for f in second_models(p.read_text(), str(p.relative_to(REPO)), tables, _views(),
                                                     schema=p.parts[-2:] == ("schema", "bench.py"))]
    assert not found, "\n".join(found)


def test_a_second_model_of_a_table_is_found():
    """The check finds what the bench file's three models were before issue 51 (an axis as a dataclass in two
    packages, a view redeclaring a key of its struct), and passes a view that only adds what a table implies."""
    tables = bench_file_tables()
    copied = '''
@dataclass(frozen=True)
class AxisConfig:
    name: str
    id: int | str
    units_per_deg: float
    zero_offset: float
'''
    assert second_models(copied, "x.py", tables, {}) == [
        "x.py: AxisConfig declares ['id', 'units_per_deg', 'zero_offset'], keys of AxisTable"]
    redeclared = "class Axis(AxisTable, kw_only=True):\n    name: str\n    model: str = 'XM430-W350'\n"
    assert second_models(redeclared, "y.py", tables, {}) == ["y.py: Axis redeclares ['model'] of AxisTable"]
    view = "class Axis(AxisTable, kw_only=True):\n    name: str\n"
    assert second_models(view, "z.py", tables, {}) == []


def test_acquisition_and_the_simulator_hand_on_the_same_axis():
    """Both readers give the drivers the one :class:`~reconstruction.schema.bench.Axis` (``AxisConfig`` was
    defined twice), with the same values for the same file."""
    from acquisition.config import load_config as acq_load
    from reconstruction.schema.bench import Axis, Detector
    from simulator.config import load_config as sim_load

    acq, sim = acq_load(REPO / "configs" / "simulated.toml"), sim_load(REPO / "configs" / "simulated.toml")
    assert type(acq.axes["light"]) is Axis and type(sim.axes["light"]) is Axis
    assert acq.axes == sim.axes
    assert type(acq.detector) is Detector and type(sim.detector) is Detector
    assert acq.detector.type == sim.detector.type and acq.detector.integration_time_s == sim.detector.integration_time_s
    assert acq.bench.name == sim.bench.name and acq.bench.motion == sim.motion
