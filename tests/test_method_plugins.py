"""Methods as plugins: a method is one module (its options declared once, as a msgspec struct with descriptions and
bounds, and a reconstruct function) plus one registry line. A toy method declared here gets its flag, its --help
text, its bounds' errors, its JSON Schema and its place in Options and the pipeline from that declaration alone;
outputs ask a reconstruction what it can give (reconstruction.base.offers), never its class."""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Annotated, Literal

import msgspec
import numpy as np
import pytest

from reconstruction import cli, methods, pipeline
from reconstruction.base import ReconstructionError
from reconstruction.core.models import Material
from reconstruction.core.slicedata import Slice
from reconstruction.formats import exports, merl
from reconstruction.job import Job
from reconstruction.methods.registry import Context
from tests.test_cli_reconstruct import slice_file

GREY = Material.from_dict({"name": "grey", "lobes": [{"type": "lambert", "albedo": [0.2, 0.3, 0.4]}]})


# --- the toy method: one module's worth -------------------------------------------------------------------------


class ToyOptions(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Options of ``toy``."""

    gain: Annotated[float, msgspec.Meta(ge=0.0, le=2.0, description="toy: the factor its diffuse level is "
                                                                    "multiplied by")] = 1.0


@dataclass
class ToyReconstruction:
    """A lambert level: the samples' median of pi f, times the gain."""

    albedo: np.ndarray
    channels: list[str]
    method: str = "toy"

    def eval(self, wi, wo):
        up = (np.asarray(wi)[:, 2] > 0) & (np.asarray(wo)[:, 2] > 0)
        return np.where(up[:, None], self.albedo[None, :] / np.pi, 0.0)

    def report(self):
        return {"method": self.method, "model": "lambert", "parameters": {"albedo": self.albedo.tolist()}}

    def analytic_lobes(self):
        return [{"type": "lambert", "albedo": self.albedo.tolist()}]


def reconstruct_toy(s: Slice, opts: ToyOptions, ctx: Context) -> ToyReconstruction:
    level = np.median(np.asarray(s.values, dtype=np.float64).reshape(len(s), -1), axis=0) * np.pi
    return ToyReconstruction(level * opts.gain, list(s.channels))


@pytest.fixture
def toy():
    method = methods.register(methods.Method("toy", "a lambert level times a gain", reconstruct=reconstruct_toy,
                                             options=ToyOptions))
    yield method
    methods.REGISTRY.pop("toy")


# --- what the declaration gives --------------------------------------------------------------------------------


def test_a_registered_toy_method_has_its_flag_and_help_from_its_declaration(toy):
    text = cli.build_parser().format_help()
    assert "--toy-gain TOY_GAIN" in text and "toy: the factor its diffuse level is multiplied by" in " ".join(
        text.split())
    assert "toy: a lambert level times a gain" in " ".join(text.split())  # --method's list of summaries
    methods_paragraph = text.split("Methods (")[1].split("auto:")[0]  # the description's list, from the registry
    assert "toy: a lambert level times a gain" in " ".join(methods_paragraph.split())
    args = cli.build_parser().parse_args(["s.csv", "--method", "toy", "--toy-gain", "1.5", "--out", "m.binary"])
    job = cli.job_from_args(args)
    assert job.method == "toy" and job.options == {"toy_gain": 1.5}
    assert job.method_options()["toy_gain"] == 1.5
    assert methods.Options().toy_gain == 1.0 and methods.Options(toy_gain=0.5).toy_gain == 0.5


def test_a_toy_option_out_of_bounds_is_one_line_and_exit_2(toy, tmp_path, capsys):
    src = slice_file(tmp_path / "s.csv", GREY)
    with pytest.raises(SystemExit) as e:
        cli.main([str(src), "--method", "toy", "--toy-gain", "3", "--out", str(tmp_path / "m.binary")])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "argument --toy-gain: expected a number from 0 to 2, got '3'" in err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "m.binary").exists()
    # from Python: the same bounds, in the method's words
    s = Slice(np.array([30.0]), np.array([-30.0]), np.ones((1, 1)), ["value"])
    with pytest.raises(ReconstructionError, match=r"^method toy: --toy-gain 5: expected a number from 0 to 2$"):
        toy.build(s, methods.Options(toy_gain=5.0))


def test_the_json_schema_lists_the_toy_method_and_its_bounded_option(toy):
    schema = methods.options_schema()
    assert schema["properties"]["toy"] == {"$ref": "#/$defs/ToyOptions", "description": toy.summary}
    gain = schema["$defs"]["ToyOptions"]["properties"]["gain"]
    assert (gain["minimum"], gain["maximum"], gain["default"]) == (0.0, 2.0, 1.0)
    assert gain["description"] == "toy: the factor its diffuse level is multiplied by (--toy-gain)"


def test_a_reconstruction_through_the_toy_method_runs_and_exports(toy, tmp_path):
    src = slice_file(tmp_path / "s.csv", GREY, incidences=(20.0, 50.0), step=4.0)
    out, params, rep = tmp_path / "m.binary", tmp_path / "p.json", tmp_path / "r.json"
    assert cli.main([str(src), "--method", "toy", "--toy-gain", "1.5", "--out", str(out), "--export-json",
                     str(params), "--report", str(rep), "--quiet"]) == 0
    assert json.loads(rep.read_text())["method"] == "toy"
    p = json.loads(params.read_text())
    # the export asked the toy for its lobes: the grey material's albedo times the gain, as Mitsuba's diffuse
    assert p["method"] == "toy" and p["analytic"] is True and p["mitsuba"]["plugins"] == ["diffuse"]
    np.testing.assert_allclose(p["lobes"][0]["albedo"], 1.5 * np.array([0.2, 0.3, 0.4]), rtol=1e-6)
    table = merl.read(out)
    np.testing.assert_allclose(np.nanmedian(table.reshape(3, -1), axis=1), 1.5 * np.array([0.2, 0.3, 0.4]) / np.pi,
                               rtol=1e-4)
    # the same through the library: a Job carries the option in its ``options``
    rep2 = pipeline.run(Job(inputs=(str(src),), out=str(tmp_path / "m2.binary"), method="toy",
                            options={"toy_gain": 0.5}))
    assert rep2["method"] == "toy"
    np.testing.assert_allclose(np.nanmedian(merl.read(tmp_path / "m2.binary").reshape(3, -1), axis=1),
                               0.5 * np.array([0.2, 0.3, 0.4]) / np.pi, rtol=1e-4)


def test_an_option_two_methods_declare_differently_is_refused(toy):
    class Clash(msgspec.Struct, frozen=True):
        fill: Annotated[Literal["zero", "mirror"], methods.option("holes", flag="--fill", attr="fill")] = "zero"

    with pytest.raises(ValueError, match=r"method clash: option fill \(--fill\) is declared differently by method "
                                         r"revolve"):
        methods.register(methods.Method("clash", "clashes", reconstruct=reconstruct_toy, options=Clash))
    assert "clash" not in methods.REGISTRY


# --- the built-in methods' flags come from their declarations ---------------------------------------------------


@pytest.mark.parametrize("flag, value, expected", [("--smoothing", "-1", "a number >= 0"),
                                                   ("--prior-near", "-1", "an integer >= 0"),
                                                   ("--prior-anchor", "x", "a number from 0 to 1")])
def test_a_built_in_option_out_of_bounds_is_a_usage_error(tmp_path, capsys, flag, value, expected):
    with pytest.raises(SystemExit) as e:
        cli.main([str(tmp_path / "s.csv"), "--out", str(tmp_path / "m.binary"), flag, value])
    assert e.value.code == 2 and f"argument {flag}: expected {expected}, got '{value}'" in capsys.readouterr().err


def test_every_flag_of_a_method_is_its_declared_option():
    from reconstruction.methods.flags import flag_specs

    flags = {s.flag: s for s in flag_specs()}
    assert list(flags) == ["--lobes", "--fill", "--axis", "--smoothing", "--prior", "--prior-anchor", "--prior-near"]
    assert {f: flags[f].attr for f in flags} == {
        "--lobes": "lobes", "--fill": "fill", "--axis": "revolve_axis", "--smoothing": "revolve_smoothing",
        "--prior": "prior", "--prior-anchor": "prior_anchor", "--prior-near": "prior_near"}
    args = cli.build_parser().parse_args(["s.csv", "--out", "m.binary", "--prior", "a", "--prior", "b", "--axis",
                                          "pca", "--lobes", "lambert,ggx"])
    job = cli.job_from_args(args)
    assert (job.prior, job.axis, job.lobes, job.options) == (f"a{__import__('os').pathsep}b", "pca",
                                                            ("lambert", "ggx"), {})
    opts = methods.Options(**job.method_options())
    assert methods.get("revolve").options_from(opts) == methods.RevolveOptions(axis="pca")


# --- outputs ask a reconstruction what it can give --------------------------------------------------------------


def test_exports_ask_for_analytic_lobes_not_the_class():
    """A reconstruction of any class that offers analytic_lobes is exported as lobes; a bounded one (Conservative)
    withdraws them (its eval is no longer their closed form) but keeps its fitted parameters."""
    from reconstruction.assess.guard import Conservative
    from reconstruction.methods.fit import reconstruct_fit
    from reconstruction.synthetic import synthetic_slice

    rec = ToyReconstruction(np.array([0.5, 0.5, 0.5]), ["R", "G", "B"])
    assert exports.parameters(rec)["lobes"] == [{"type": "lambert", "albedo": [0.5, 0.5, 0.5]}]
    fit = reconstruct_fit(synthetic_slice(GREY, [20.0, 50.0], step_deg=5.0), lobes=["lambert"])
    p = exports.parameters(fit)
    assert p["analytic"] and p["lobes"][0]["type"] == "lambert" and p["uncertainties"] == fit.fitted_parameters()
    bounded = Conservative(fit, np.zeros((3, 90, 90, 180)), np.zeros((90, 90, 180), bool))
    q = exports.parameters(bounded)
    assert not q["analytic"] and q["lobes"] == [] and q["uncertainties"] == fit.fitted_parameters()
