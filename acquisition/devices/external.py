"""The detectors that are not the board's, built from the bench file: ``[detector] type = "seabreeze"``
(:mod:`acquisition.devices.seabreeze`) and ``type = "pm100"`` (:mod:`acquisition.devices.pm100`).

:func:`external_detector` is what their drivers (:data:`SEABREEZE_DRIVER`, :data:`PM100_DRIVER`, registered in
:mod:`acquisition.devices.registry`) open. ``library`` is the detector's
library: None for the real one (imported now, with one line naming what to install when it is missing), or a
stand-in that a test passes through ``Bench.detector_library`` (docs/detectors.md: the simulator's stand-ins
read the simulated world; nothing in acquisition imports them).
"""

from __future__ import annotations

from typing import Any

from acquisition.config import BenchConfig
from acquisition.devices.driver import Driver, Opening, Port
from acquisition.devices.pm100 import Pm100Detector, band_centroid_nm, import_pyvisa
from acquisition.devices.seabreeze import SeabreezeDetector, import_seabreeze
from acquisition.devices.serial_link import SerialLink
from acquisition.errors import ConfigError, DeviceError
from reconstruction.schema.bench import DetectorTable

__all__ = ["EXTERNAL_TYPES", "external_detector", "external_library", "check_external_library", "SEABREEZE_DRIVER",
           "PM100_DRIVER"]

#: ``[detector].type`` values whose detector is not the board's.
EXTERNAL_TYPES = ("seabreeze", "pm100")


def external_library(cfg: BenchConfig, simulated: bool = False) -> Any:
    """The real library of ``cfg``'s detector (``seabreeze.spectrometers`` or ``pyvisa.ResourceManager``), checked
    before any port is opened: a missing package, or a simulated bench (whose detector only a stand-in reads), is
    a :class:`ConfigError` in one line naming what to do."""
    d = cfg.detector
    if simulated:
        what = "spectrometer" if d.type == "seabreeze" else "power meter"
        raise ConfigError(f'{cfg.path}: [detector].type = "{d.type}": the simulator serves the {what}\'s world to a '
                          "stand-in of its library, which only the test hook Bench.detector_library passes in "
                          "(docs/detectors.md); capture it on the real device, or simulate the board's "
                          'detector (type = "photodiode" or "spectrometer")')
    try:
        return import_seabreeze() if d.type == "seabreeze" else import_pyvisa()
    except DeviceError as e:
        raise ConfigError(f"{cfg.path}: {e}") from None


def check_external_library(cfg: BenchConfig) -> None:
    """What ``--check`` asks of an external detector's library: :func:`external_library` imports it, and for a
    PM100 pyvisa must also find a VISA library underneath (``pyvisa.ResourceManager()`` raises without one; it only
    loads the library, no instrument is opened). A :class:`ConfigError` in one line naming what to install."""
    lib = external_library(cfg)
    if cfg.detector.type != "pm100":
        return
    from acquisition.devices.pm100 import INSTALL_HINT

    try:
        rm = lib()
    except Exception as e:  # noqa: BLE001 - ValueError / OSError: no VISA implementation underneath pyvisa
        raise ConfigError(f'{cfg.path}: [detector].type = "pm100": pyvisa has no VISA library to use ({e}); '
                          f"{INSTALL_HINT}") from None
    try:
        rm.close()
    except Exception:  # noqa: BLE001 - closing what was only opened to check it
        pass


def external_detector(cfg: BenchConfig, link: SerialLink | None, library: Any) -> SeabreezeDetector | Pm100Detector:
    """The (unconnected) detector of ``cfg``'s ``[detector]`` for a bench whose board is on ``link`` (None: no
    board), through ``library``: ``seabreeze.spectrometers`` or ``pyvisa.ResourceManager`` (:func:`external_library`),
    or a stand-in of it."""
    d = cfg.detector
    if d.type == "seabreeze":
        return SeabreezeDetector(library, d.serial_number,
                                 d.integration_time_s, d.saturation, d.correct_dark_counts, d.correct_nonlinearity,
                                 link, d.source_off, d.min_integration_time_s)
    if d.type == "pm100":
        nm = d.wavelength_nm if d.wavelength_nm is not None else band_centroid_nm(d.band_weights)
        return Pm100Detector(library, d.resource, d.integration_time_s,
                             nm, d.gains, start_gain=max(d.gains) if d.gains and d.auto_range else None, link=link,
                             source_off=d.source_off)
    raise DeviceError(f"{cfg.path}: [detector].type = {d.type!r} is the board's detector, not an external one")


def _open(o: Opening) -> SeabreezeDetector | Pm100Detector:
    return external_detector(o.cfg, o.link, o.library)


#: The board beside a USB detector: its clock, sample changer and source pin when the file gives its port.
_BOARD = Port("serial", "[bench].serial_port", "[bench].serial_baudrate", "detector controller", required=False)
#: ``[detector].type = "seabreeze"`` and ``"pm100"`` (:mod:`acquisition.devices.registry`): a USB instrument through
#: its library, beside the detector board when there is one.
SEABREEZE_DRIVER = Driver("seabreeze", "detector", DetectorTable, (_BOARD,), _open, library=external_library)
PM100_DRIVER = Driver("pm100", "detector", DetectorTable, (_BOARD,), _open, library=external_library)
