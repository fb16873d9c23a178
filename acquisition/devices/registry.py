"""The drivers by the bench file's ``type``: one line per driver. :class:`acquisition.bench.Bench` looks up the
arms' driver by ``[bench].motion`` (``[motion].type``) and the detector's by ``[detector].type``, and opens and
closes the devices through them; :mod:`acquisition.ports` checks the ports they declare. A new driver is one
module (its device and its :class:`~acquisition.devices.driver.Driver`) and one :func:`register` line here;
``tests/test_drivers_registry.py`` shows it with a stand-in driver.
"""

from __future__ import annotations

from acquisition.devices import dynamixel, external, grbl, serial_link
from acquisition.devices.driver import Driver
from acquisition.errors import ConfigError

__all__ = ["REGISTRY", "register", "driver_for"]

#: (role, type) -> driver.
REGISTRY: dict[tuple[str, str], Driver] = {}


def register(driver: Driver) -> Driver:
    """Add ``driver`` under its role and type (a type registered twice for a role is a programming error)."""
    key = (driver.role, driver.type)
    if key in REGISTRY and REGISTRY[key] is not driver:
        raise ValueError(f"a {driver.role} driver of type {driver.type!r} is registered already")
    REGISTRY[key] = driver
    return driver


register(dynamixel.DRIVER)
register(serial_link.AXES_DRIVER)
register(grbl.DRIVER)
register(serial_link.PHOTODIODE_DRIVER)
register(serial_link.SPECTROMETER_DRIVER)
register(external.SEABREEZE_DRIVER)
register(external.PM100_DRIVER)


def driver_for(role: str, type_: str, source: object = "config") -> Driver:
    """The driver of ``role`` (``"motion"``, ``"detector"``) for the bench file's ``type_``; a type no driver
    answers to is a :class:`ConfigError` naming ``source``'s key and the known types."""
    try:
        return REGISTRY[(role, type_)]
    except KeyError:
        key = "[bench].motion" if role == "motion" else "[detector].type"
        known = ", ".join(sorted(t for r, t in REGISTRY if r == role))
        raise ConfigError(f"{source}: {key}: no {role} driver for {type_!r}; known: {known}") from None
