"""What a GRBL 1.1 stepper bench is, before a port is opened: the bench file's ``[motion] type = "grbl"`` and
``[motion.grbl]`` read and checked, the ``$$`` settings the bench file implies, and GRBL's ``error:N`` and
``ALARM:N`` codes as one sentence each.

GRBL speaks millimetres; on this bench an axis' "mm" is a degree of the *machine* coordinate::

    steps = zero_offset + direction * units_per_deg * deg       ([axes.*], as every stepper bench)
    MPos  = steps / units_per_deg                                 (GRBL's machine position, "mm" = degrees)

so ``$100``/``$101`` (X = light arm, Y = detector arm) are ``units_per_deg`` steps per degree, ``$110``/``$111``
the top speed in deg/min (60 x ``[motion].velocity_deg_s``) and ``$120``/``$121`` the acceleration in deg/s^2
(``[motion].acceleration_deg_s2``). With soft limits GRBL keeps every machine coordinate within ``[-$130, 0]``
(homing to the positive end, its default), so the arms' soft limits must map there.

The code sentences are our own short wording of the tables GRBL documents (gnea/grbl ``doc/csv/
error_codes_en_US.csv``, ``alarm_codes_en_US.csv`` and ``doc/markdown/interface.md``, GRBL 1.1h); nothing of
GRBL is copied or read at run time.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import msgspec

from acquisition.errors import ConfigError
from reconstruction.schema import SchemaError, Table
from reconstruction.schema.bench import Axis, GrblTable, MotionTable

__all__ = ["ERRORS", "ALARMS", "LOST_POSITION_ALARMS", "MAX_STEP_RATE", "AXIS_LETTER", "error_text", "alarm_text",
           "motion_kind", "read_grbl", "unlocked", "machine_deg", "expected_settings", "SETTING_NAMES"]

#: GRBL 1.1 ``error:N`` codes (gnea/grbl doc/csv/error_codes_en_US.csv), in our words.
ERRORS = {
    1: "a G-code word lacks its letter",
    2: "a number is missing or badly formatted",
    3: "the '$' command is not recognised",
    4: "a negative value where a positive one is expected",
    5: "homing is not enabled in the settings ($22)",
    6: "the step pulse time must be at least 3 microseconds",
    7: "the EEPROM could not be read; GRBL restored its default settings",
    8: "a '$' command that needs GRBL idle was sent while it was busy",
    9: "G-code is locked out during an alarm or a jog (home with $H or unlock with $X)",
    10: "soft limits cannot be enabled without homing",
    11: "the line is longer than GRBL accepts and was not executed",
    12: "the setting would make the step rate exceed what GRBL supports",
    13: "the safety door is open",
    14: "the build info or startup line is too long for the EEPROM",
    15: "the jog target lies outside the machine travel",
    16: "the jog command has no '=' or contains forbidden G-code",
    17: "laser mode needs PWM output",
    20: "unsupported or invalid G-code command",
    21: "two G-code commands of the same modal group in one line",
    22: "the feed rate is not set",
    23: "the G-code command needs an integer value",
    24: "two G-code commands in one line both need the axis words",
    25: "a G-code word is repeated in the line",
    26: "the G-code command needs axis words and none were given",
    27: "the line number is invalid",
    28: "the G-code command is missing a required value word",
    29: "G59.x work coordinate systems are not supported",
    30: "G53 is only allowed with G0 and G1",
    31: "axis words given where no command uses them",
    32: "a G2/G3 arc needs at least one axis word in the plane",
    33: "the motion target is invalid",
    34: "the arc radius is invalid",
    35: "a G2/G3 arc needs at least one offset word in the plane",
    36: "unused value words are left in the line",
    37: "the dynamic tool length offset is not on the tool length axis",
    38: "the tool number is larger than supported",
}

#: GRBL 1.1 ``ALARM:N`` codes (gnea/grbl doc/csv/alarm_codes_en_US.csv), in our words.
ALARMS = {
    1: "hard limit switch triggered: the arms stopped at once and their position is likely lost; home them",
    2: "soft limit: a move target lies outside the machine travel ($130/$131); the position was kept",
    3: "reset while moving: the position is likely lost (steps missed in the sudden stop); home the arms",
    4: "probe fail: the probe was not in its expected state before the probe cycle",
    5: "probe fail: the probe did not make contact within the programmed travel",
    6: "homing failed: the homing cycle was reset",
    7: "homing failed: the safety door was opened during homing",
    8: "homing failed: the pull-off did not clear the limit switch (raise $27 or check the wiring)",
    9: "homing failed: no limit switch within the search distance (check $130/$131, $27 and the wiring)",
    10: "homing failed: the second switch of a dual axis did not trigger",
}
#: Alarms after which GRBL's idea of the arms' position cannot be trusted (all but the soft limit's, 2).
LOST_POSITION_ALARMS = frozenset(ALARMS) - {2}

#: Highest step rate of GRBL 1.1 on a 16 MHz ATmega328P (steps/s, its documentation's figure).
MAX_STEP_RATE = 30000.0
#: GRBL axis of each arm.
AXIS_LETTER = {"light": "X", "detector": "Y"}

#: What each checked ``$`` setting is (GRBL's setting codes, doc/csv/setting_codes_en_US.csv).
SETTING_NAMES = {
    10: "status report mask (bit 0: report MPos)",
    20: "soft limits enable",
    22: "homing cycle enable",
    100: "X steps per degree (light arm)",
    101: "Y steps per degree (detector arm)",
    110: "X maximum rate, deg/min",
    111: "Y maximum rate, deg/min",
    120: "X acceleration, deg/s^2",
    121: "Y acceleration, deg/s^2",
    130: "X maximum travel, deg",
    131: "Y maximum travel, deg",
}


def error_text(code: int) -> str:
    """One sentence for GRBL's ``error:code``."""
    return f"error:{code}: " + ERRORS.get(code, "an error code GRBL 1.1 does not document")


def alarm_text(code: int) -> str:
    """One sentence for GRBL's ``ALARM:code``."""
    return f"ALARM:{code}: " + ALARMS.get(code, "an alarm code GRBL 1.1 does not document")


def motion_kind(src: str, bench_motion: Any, motion_type: Any, transport: str) -> Any:
    """The bench's motion hardware from ``[bench].motion`` and ``[motion].type`` (the issue's name): equal when
    both are given; ``[motion].type`` alone counts as ``[bench].motion``. Values are checked by the schema."""
    if motion_type is None:
        return bench_motion
    if bench_motion is not None and bench_motion != motion_type:
        raise ConfigError(f"{src}: [motion].type: is {motion_type!r} but [bench].motion is {bench_motion!r}; "
                          "give one of them, or make them equal")
    if motion_type == "grbl" or transport == "simulated":
        return motion_type
    return bench_motion


def machine_deg(ax: Axis, deg: float) -> float:
    """GRBL's machine coordinate (its "mm": degrees of the motor side) of the arm angle ``deg``."""
    return ax.deg_to_units(deg) / ax.units_per_deg


def read_grbl(src: str, raw_motion: Mapping[str, Any], motion: MotionTable, axes: Mapping[str, Axis],
              transport: str) -> MotionTable:
    """``[motion.grbl]`` checked against the arms: returns ``motion`` with its :class:`GrblTable` (defaults when
    the table is left out). Raises :class:`ConfigError` naming the file and key."""
    sec = "motion.grbl"
    raw = raw_motion.get("grbl", {})
    try:
        t = Table(src, sec, raw, GrblTable)
    except SchemaError as e:
        raise ConfigError(str(e)) from None
    g = t.build()
    if transport != "simulated" and not g.port:
        raise ConfigError(f'{src}: [{sec}].port: missing: a GRBL bench needs the controller\'s port, e.g. '
                          '"/dev/ttyUSB0" (serial_port of [bench] is the detector\'s)')
    if g.soft_limits and not g.homing:
        raise ConfigError(f"{src}: [{sec}].soft_limits: GRBL enables soft limits only with homing (its error:10); "
                          "set homing = true (the arms need switches) or soft_limits = false")
    if "stage" in axes:
        raise ConfigError(f"{src}: [axes.stage]: a GRBL bench drives the two arms (X, Y) only; remove the stage")
    for name, letter in AXIS_LETTER.items():
        ax = axes[name]
        if ax.letter != letter:
            raise ConfigError(f"{src}: [axes.{name}].id: the {name} arm is GRBL's {letter} axis; set id = "
                              f'"{letter}", got {ax.id!r}')
        rate = ax.units_per_deg * motion.velocity_deg_s
        if rate > MAX_STEP_RATE:
            raise ConfigError(f"{src}: [motion].velocity_deg_s: {motion.velocity_deg_s:g} deg/s x "
                              f"{ax.units_per_deg:g} steps/deg ([axes.{name}].units_per_deg) = {rate:.0f} steps/s, "
                              f"more than GRBL's {MAX_STEP_RATE:.0f}")
        if g.soft_limits:
            lo, hi = sorted((machine_deg(ax, ax.min_deg), machine_deg(ax, ax.max_deg)))
            if hi > 1e-6:
                raise ConfigError(f"{src}: [axes.{name}].zero_offset: with soft limits GRBL's machine coordinates "
                                  f"run from -$13{'01'[name == 'detector']} to 0 (0 at the home switch), but "
                                  f"[{ax.min_deg:g}, {ax.max_deg:g}] deg map to [{lo:.3f}, {hi:.3f}]; put the "
                                  "switch end of the travel at machine 0")
    return msgspec.structs.replace(motion, type="grbl", grbl=g)


def unlocked(cfg: Any) -> MotionTable:
    """``cfg.motion`` with ``[motion.grbl].unlock`` set (``gonio-capture --unlock``); a bench that is not on GRBL
    raises :class:`ConfigError`."""
    if cfg.motion.type != "grbl" or cfg.motion.grbl is None:
        raise ConfigError(f'{cfg.path}: --unlock is for a GRBL bench ([motion] type = "grbl"); this bench\'s motion '
                          f"is {cfg.bench.motion!r}")
    return msgspec.structs.replace(cfg.motion, grbl=msgspec.structs.replace(cfg.motion.grbl, unlock=True))


def expected_settings(axes: Mapping[str, Axis], motion: MotionTable) -> dict[int, float]:
    """The ``$N`` values the bench file implies (GRBL units: deg for mm), keyed by setting number."""
    g = motion.grbl if motion.grbl is not None else GrblTable()
    out: dict[int, float] = {22: float(g.homing), 20: float(g.soft_limits)}
    for i, name in enumerate(("light", "detector")):
        ax = axes[name]
        out[100 + i] = ax.units_per_deg
        out[110 + i] = motion.velocity_deg_s * 60.0
        out[120 + i] = motion.acceleration_deg_s2
        if g.soft_limits:
            out[130 + i] = max(-machine_deg(ax, ax.min_deg), -machine_deg(ax, ax.max_deg))
    return out
