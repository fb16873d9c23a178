"""The detectors labs already own (docs/detectors.md): Ocean Insight spectrometers through python-seabreeze and
Thorlabs PM100 power meters through pyvisa, tested at each library's boundary.

- The PM100's SCPI dialogue against pyvisa itself, with pyvisa-sim (tests/data/pm100-sim.yaml): settings sent and
  read back, a reading turned into counts, "no sensor" and over-range in one line each.
- Whole simulated captures through the stand-ins of the libraries (simulator/devices/*_standin.py, fed the
  simulator's physics on the bench's usb port), compared with the board's own detectors on the same material and
  seed: a PM100 with a photodiode's board, a seabreeze spectrometer with the board's spectrometer.
- The one-line errors of a missing library, a missing device, a source that cannot be turned off.
"""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
import tomli_w

from acquisition.errors import DeviceError

pytestmark = pytest.mark.slow

YAML = Path(__file__).parent / "data" / "pm100-sim.yaml"
PM100_OK = "USB0::0x1313::0x8072::P2000001::INSTR"
GLOSSY = {"name": "glossy-blue", "lobes": [{"type": "lambert", "albedo": [0.05, 0.10, 0.40]},
                                          {"type": "ggx", "alpha": 0.15, "specular": 1.0}]}


def _sim_rm() -> Any:
    pyvisa = pytest.importorskip("pyvisa", reason="pyvisa is in the test extra: pip install -e '.[test]'")
    pytest.importorskip("pyvisa_sim", reason="pyvisa-sim is in the test extra: pip install -e '.[test]'")
    return lambda: pyvisa.ResourceManager(f"{YAML}@sim")


# -- the PM100's SCPI dialogue, checked by pyvisa-sim ------------------------------------------------------------


def test_pm100_dialogue_with_pyvisa_sim():
    from acquisition.devices.pm100 import COUNTS_PER_WATT, SAMPLE_S, Pm100Detector

    d = Pm100Detector(_sim_rm(), PM100_OK, 0.01, 550.0, gains=(1.0, 10.0, 100.0), start_gain=100.0)
    d.connect()
    try:
        q = d.inst.query
        assert float(q("SENS:CORR:WAV?")) == 550.0          # wavelength correction sent as set
        assert int(q("SENS:AVER:COUN?")) == round(0.01 / SAMPLE_S)  # averaging as the integration time
        assert d.integration_time_s == pytest.approx(3 * SAMPLE_S)
        assert q("SENS:POW:RANG:AUTO?") == "OFF"             # fixed ranges on the gain ladder
        assert float(q("SENS:POW:RANG?")) == pytest.approx(5e-4)  # gain 100: the top range (50 mW) / 100
        assert d.gain == pytest.approx(100.0)
        rd = d.read(3)
        assert rd.mean[0] == pytest.approx(1.2345e-6 * COUNTS_PER_WATT * 100.0)  # watts -> counts x gain
        assert rd.saturated == 0 and rd.n == 3
        assert d.set_gain(10.0) == pytest.approx(10.0) and float(q("SENS:POW:RANG?")) == pytest.approx(5e-3)
        assert d.saturation == pytest.approx(5e-2 * COUNTS_PER_WATT)  # every range clips at the top range's count
    finally:
        d.close()


def test_pm100_own_auto_range_reads_watts_as_counts():
    from acquisition.devices.pm100 import Pm100Detector

    d = Pm100Detector(_sim_rm(), None, 0.01, 633.0)  # the first Thorlabs resource found
    d.connect()
    try:
        assert d.resource.startswith("USB0::0x1313::")
        assert d.inst.query("SENS:POW:RANG:AUTO?") == "ON"
        assert d.read(2).mean[0] == pytest.approx(1234.5)  # 1.2345 uW, one count a nanowatt
    finally:
        d.close()


@pytest.mark.parametrize(("resource", "words"), [
    ("USB0::0x1313::0x8072::P2000002::INSTR", ["no power sensor head", "plug a photodiode sensor in"]),
    ("USB0::0x1313::0x8072::P2000003::INSTR", ["over range", "top range (0.05 W)", "neutral density filter"]),
])
def test_pm100_no_sensor_and_over_range_are_one_line(resource, words):
    from acquisition.devices.pm100 import Pm100Detector

    d = Pm100Detector(_sim_rm(), resource, 0.01, 633.0)
    with pytest.raises(DeviceError) as e:
        d.connect()
        d.read(2)
    d.close()
    msg = str(e.value)
    assert "\n" not in msg and all(w in msg for w in words), msg


# -- whole captures through the stand-ins -------------------------------------------------------------------------


def _capture(base: dict[str, Any], tmp: Path, kind: str, over: dict[str, Any] | None = None) -> Any:
    from acquisition import Bench
    from reconstruction.formats.slicefile import read_slice
    from tests.helpers import deep_merge

    # stepper arms on the text protocol (retried on a late reply): the Dynamixel SDK's wall-clock deadline is
    # what a machine under load misses, not what is tested here
    cfg = deep_merge(base, {"bench": {"motion": "serial"}, "detector": {"type": kind}, "material": GLOSSY,
                            "simulator": {"seed": 11, "spectrometer": {"wl_step_nm": 20.0}},
                            "plan": {"theta_i_deg": [20.0, 50.0], "theta_o_step_deg": 5.0}, **(over or {})})
    cfg["material"] = GLOSSY
    if kind in ("seabreeze", "pm100"):
        del cfg["detector"]["saturation"]  # read from the device
    if kind in ("seabreeze", "spectrometer"):
        del cfg["detector"]["gains"]
    path = tmp / f"{kind}.toml"
    path.write_text(tomli_w.dumps(cfg))
    bench = Bench.from_config(path)
    if kind == "seabreeze":
        from simulator.devices import seabreeze_standin

        bench.detector_library = seabreeze_standin.library
    elif kind == "pm100":
        from simulator.devices import pm100_standin

        bench.detector_library = pm100_standin.library
    r = bench.capture(out=tmp / f"out-{kind}", progress=False, handle_signals=False)
    assert r.ok, r.message
    return read_slice(tmp / f"out-{kind}" / "slice.csv"), r, (tmp / f"out-{kind}" / "capture.log").read_text()


@pytest.fixture(scope="module")
def captures(tmp_path_factory, base_config_dict) -> dict[str, Any]:
    tmp = tmp_path_factory.mktemp("detectors")
    bright = {"simulator": {"seed": 11, "source_power": 2.0e7, "spectrometer": {"wl_step_nm": 20.0}}}
    return {"photodiode": _capture(base_config_dict, tmp, "photodiode"),
            "pm100": _capture(base_config_dict, tmp, "pm100"),
            "spectrometer": _capture(base_config_dict, tmp, "spectrometer", bright),
            "seabreeze": _capture(base_config_dict, tmp, "seabreeze", bright)}


def _agreement(a: Any, b: Any) -> tuple[float, float, float]:
    """(median, max relative difference of f_r over the values >= 10 % of the peak, 99th percentile of the
    difference in combined standard deviations, the calibrations' common uncertainties included: the standard
    deviations of 4 repeats are themselves uncertain, so the differences have heavier tails than a normal's)."""
    assert np.allclose(a.theta_i_deg, b.theta_i_deg) and np.allclose(a.theta_o_deg, b.theta_o_deg)
    keep = a.values >= 0.1 * a.values.max()
    rel = (np.abs(b.values - a.values) / np.abs(a.values))[keep]
    common = [np.asarray(s.meta["calibration"]["common_relative_uncertainty"]) * s.values for s in (a, b)]
    sd = np.sqrt(a.std ** 2 + b.std ** 2 + common[0] ** 2 + common[1] ** 2)
    return float(np.median(rel)), float(rel.max()), float(np.percentile(np.abs(b.values - a.values) / sd, 99))


def test_pm100_capture_agrees_with_the_boards_photodiode(captures):
    (board, _, _), (meter, res, log) = captures["photodiode"], captures["pm100"]
    med, top, z = _agreement(board, meter)
    # measured: median 0.03 %, max 0.24 % (60 samples, a glossy lobe of f_r up to 8.4 / sr; docs/detectors.md)
    assert med < 0.005 and top < 0.02 and z < 5, (med, top, z)
    assert meter.meta["detector"]["type"] == "pm100" and meter.channels == ["value"]
    assert "auto-ranged to t_int" in log and ", gain 1000" in log  # the specular lobe on a less sensitive range
    assert res.bench_clock == "controller"  # the board's clock: the meter's averaging took simulated time


def test_seabreeze_capture_agrees_with_the_boards_spectrometer(captures):
    from reconstruction.core.colour import spectra_to_rgb

    (board, _, _), (spec, _, log) = captures["spectrometer"], captures["seabreeze"]
    assert spec.wavelengths_nm is not None and np.allclose(spec.wavelengths_nm, board.wavelengths_nm)
    med, top, z = _agreement(board, spec)
    # measured: median 0.03 %, max 0.19 % (60 samples x 21 wavelengths; docs/detectors.md)
    assert med < 0.005 and top < 0.02 and z < 5, (med, top, z)
    rgb_a, _ = spectra_to_rgb(board.values, board.wavelengths_nm)  # the spectral-to-RGB path
    rgb_b, _ = spectra_to_rgb(spec.values, spec.wavelengths_nm)
    keep = rgb_a >= 0.1 * rgb_a.max()
    assert np.median(np.abs(rgb_b - rgb_a)[keep] / rgb_a[keep]) < 0.01
    assert "dark-count correction on, non-linearity correction off" in log  # what the stand-in device offers
    assert "darks with the source off by the detector board's SOURCE pin" in log
    assert "auto-ranged to t_int = 0.00" in log  # integration time walked down on the specular peak
    dark = np.asarray(spec.meta["calibration"]["dark"]["mean"])
    ref = np.asarray(spec.meta["calibration"]["reference_reading"]["mean"])
    assert np.all(np.abs(dark) < 5) and np.all(ref > 100 * np.maximum(np.abs(dark), 1))  # the source was off


# -- one clear line ---------------------------------------------------------------------------------------------


def test_missing_libraries_name_what_to_install(monkeypatch):
    from acquisition.devices.pm100 import import_pyvisa
    from acquisition.devices.seabreeze import import_seabreeze

    monkeypatch.setitem(sys.modules, "seabreeze", None)
    monkeypatch.setitem(sys.modules, "seabreeze.spectrometers", None)
    monkeypatch.setitem(sys.modules, "pyvisa", None)
    with pytest.raises(DeviceError, match=r"pip install 'gonio-brdf\[seabreeze\]'"):
        import_seabreeze()
    with pytest.raises(DeviceError, match=r"pip install 'gonio-brdf\[pm100\]'"):
        import_pyvisa()


class _NoSuchDevice(Exception):
    pass


def _library(devices: list[Any]) -> Any:
    def from_serial_number(serial: str | None) -> Any:
        raise _NoSuchDevice(f"No device attached with serial number '{serial}'.")

    return SimpleNamespace(list_devices=lambda: devices, SeaBreezeError=_NoSuchDevice,
                           Spectrometer=SimpleNamespace(from_serial_number=from_serial_number))


def test_missing_spectrometer_says_plug_it_in():
    from acquisition.devices.seabreeze import SeabreezeDetector

    with pytest.raises(DeviceError, match="no spectrometer found by python-seabreeze.*plug it in"):
        SeabreezeDetector(_library([]), None, 0.01).connect()
    other = SimpleNamespace(model="FLAME-S", serial_number="FLMS01234")
    with pytest.raises(DeviceError, match=r"serial number 'USB2\+H0001'.*connected: FLAME-S FLMS01234"):
        SeabreezeDetector(_library([other]), "USB2+H0001", 0.01).connect()


def test_a_simulated_external_detector_without_its_stand_in_is_one_line(tmp_path, config_file, capsys):
    from acquisition.cli import main

    cfg = config_file({"detector": {"type": "seabreeze"}, "plan": {"theta_i_deg": [30.0]}})
    assert main(["--config", str(cfg), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "Bench.detector_library" in err and "docs/detectors.md" in err, err
    assert len(err.strip().splitlines()) == 1 and err.strip().endswith("; nothing was moved"), err


@pytest.mark.parametrize(("kind", "module", "extra"), [("seabreeze", "seabreeze", "seabreeze"),
                                                        ("pm100", "pyvisa", "pm100")])
def test_check_says_which_package_a_real_bench_lacks(tmp_path, repo_root, monkeypatch, capsys, kind, module, extra):
    import tomllib

    from acquisition.cli import main

    raw = tomllib.loads((repo_root / "configs" / "dynamixel-bench.toml").read_text())
    raw["detector"].update(type=kind)
    raw["detector"].pop("saturation", None)
    raw["bench"]["serial_port"] = ""  # a USB detector on a Dynamixel bench needs no detector board
    cfg = tmp_path / "bench.toml"
    cfg.write_text(tomli_w.dumps(raw))
    monkeypatch.setitem(sys.modules, module, None)
    monkeypatch.setitem(sys.modules, f"{module}.spectrometers", None)
    assert main(["--config", str(cfg), "--check"]) == 2
    err = capsys.readouterr().err
    assert f"pip install 'gonio-brdf[{extra}]'" in err and "Traceback" not in err, err
    assert len(err.strip().splitlines()) == 1 and err.strip().endswith("; nothing was moved"), err


def test_dark_ways_that_the_bench_lacks_are_refused():
    from acquisition.devices.board import BoardBacked

    b = BoardBacked(None, "shutter", name="spectrometer")
    with pytest.raises(DeviceError, match="source_off = 'shutter', but the device has no shutter"):
        b.connect_board()
    b = BoardBacked(None, "auto", name="spectrometer")
    b.operator = None
    b.connect_board()
    with pytest.raises(DeviceError, match="cannot read a dark"):
        b.with_source_off(lambda n: None, 4)  # type: ignore[arg-type,return-value]
    closed: list[bool] = []
    b = BoardBacked(None, "auto", name="spectrometer")
    b.shutter = closed.append
    b.connect_board()
    b.with_source_off(lambda n: None, 4)  # type: ignore[arg-type,return-value]
    assert b.dark_way == "shutter" and closed == [False, True]  # closed for the dark, open again after


def test_the_seabreeze_stand_in_has_the_librarys_signatures():
    """Where python-seabreeze is installed (the [seabreeze] extra), the stand-in's calls take the same parameters
    with the same defaults as the library's (checked by hand against python-seabreeze 2.11's source otherwise)."""
    import inspect

    real = pytest.importorskip("seabreeze.spectrometers", reason="python-seabreeze is not installed here (it is the "
                                                                 "optional [seabreeze] extra, not a test dependency)")
    from simulator.devices.seabreeze_standin import StandInSpectrometer

    for name in ("intensities", "integration_time_micros", "wavelengths", "close", "from_serial_number"):
        want = inspect.signature(getattr(real.Spectrometer, name)).parameters
        have = inspect.signature(getattr(StandInSpectrometer, name)).parameters
        assert [(p.name, p.default) for p in have.values()] == [(p.name, p.default) for p in want.values()], name


@pytest.mark.parametrize(("name", "kind"), [("ocean-insight-bench", "seabreeze"), ("pm100-bench", "pm100")])
def test_the_example_benches_validate(repo_root, name, kind):
    from acquisition.config import load_config

    cfg = load_config(repo_root / "configs" / f"{name}.toml")
    assert cfg.detector.type == kind and not cfg.detector.on_board and cfg.detector.saturation is None
    if kind == "pm100":  # ranges over its ranges, not over averaging
        assert cfg.detector.min_integration_time_s == cfg.detector.integration_time_s and cfg.detector.gains
