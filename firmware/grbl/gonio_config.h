/*
  gonio_config.h - gonio-brdf's build configuration of GRBL 1.1h for a two-arm in-plane gonioreflectometer.

  The Makefile copies GRBL's grbl/ folder into the build folder, renames GRBL's own config.h there to
  grbl_config_stock.h and installs this file as config.h: GRBL's options are read first, then the few below
  replace them. Nothing of GRBL's code is in this file; every choice says why (docs/build-a-bench.md).

  Machine: X = light arm, Y = detector arm, both rotary ("mm" = degrees); no Z axis, no spindle, no coolant.
  One limit switch per arm, at its max_deg end (homing towards +, $23=0), which becomes machine 0.
*/

#ifndef gonio_config_h
#define gonio_config_h

#include "grbl_config_stock.h"  // GRBL 1.1h's own config.h (renamed in the build copy)

/* Homing: stock GRBL homes Z first (HOMING_CYCLE_0 = Z). A two-arm bench has no Z switch, so stock `$H` seeks Z
   for 1.5 x $132, never finds a switch and ends in ALARM:9; the arms never move. Our cycle homes both arms at
   once: the light arm turns outwards on its side and the detector arm outwards on the other, away from each
   other, so homing both together cannot bring them into collision, and takes one seek instead of two. */
#undef HOMING_CYCLE_0
#undef HOMING_CYCLE_1
#undef HOMING_CYCLE_2
#define HOMING_CYCLE_0 ((1 << X_AXIS) | (1 << Y_AXIS))

/* $HX / $HY home one arm (still inside the same switch logic): a lab checks each switch on its own at first
   light, and can re-home one arm without moving the other. It also puts an 'H' in `$I`'s [OPT:] line, which is
   how the driver tells this build from the stock one (whose homing cannot work on this bench). */
#define HOMING_SINGLE_AXIS_COMMANDS

/* Defaults: `$RST=$` restores the bench's settings (configs/grbl-bench.toml) instead of a 3-axis mill's, so a
   freshly flashed or reset board already agrees with the bench file the driver checks. GRBL reads these only
   when it (re)initialises its EEPROM. Units: steps/deg, deg/min, deg/min^2 (GRBL's mm/min^2), deg. */
#undef DEFAULTS_GENERIC
#define DEFAULT_X_STEPS_PER_MM 44.444      // 200 steps x 16 microsteps x 5:1 belt / 360 deg
#define DEFAULT_Y_STEPS_PER_MM 44.444
#define DEFAULT_Z_STEPS_PER_MM 250.0       // no Z axis: GRBL's own default, unused
#define DEFAULT_X_MAX_RATE 3600.0          // 60 deg/s
#define DEFAULT_Y_MAX_RATE 3600.0
#define DEFAULT_Z_MAX_RATE 500.0
#define DEFAULT_X_ACCELERATION (240.0 * 60 * 60)  // 240 deg/s^2
#define DEFAULT_Y_ACCELERATION (240.0 * 60 * 60)
#define DEFAULT_Z_ACCELERATION (10.0 * 60 * 60)
#define DEFAULT_X_MAX_TRAVEL 80.0          // light arm: 0..80 deg from its switch
#define DEFAULT_Y_MAX_TRAVEL 170.0         // detector arm: -85..85 deg
#define DEFAULT_Z_MAX_TRAVEL 200.0
#define DEFAULT_SPINDLE_RPM_MAX 1000.0
#define DEFAULT_SPINDLE_RPM_MIN 0.0
#define DEFAULT_STEP_PULSE_MICROSECONDS 10
#define DEFAULT_STEPPING_INVERT_MASK 0
#define DEFAULT_DIRECTION_INVERT_MASK 0
#define DEFAULT_STEPPER_IDLE_LOCK_TIME 255 // keep the motors energised: an arm must hold its angle while measuring
#define DEFAULT_STATUS_REPORT_MASK 1       // MPos in status reports (the driver reads machine positions)
#define DEFAULT_JUNCTION_DEVIATION 0.01
#define DEFAULT_ARC_TOLERANCE 0.002
#define DEFAULT_REPORT_INCHES 0
#define DEFAULT_INVERT_ST_ENABLE 0
#define DEFAULT_INVERT_LIMIT_PINS 0        // normally-open switches to GND, GRBL's pull-ups
#define DEFAULT_SOFT_LIMIT_ENABLE 1        // refuse targets outside [-$130, 0] (ALARM:2, position kept)
#define DEFAULT_HARD_LIMIT_ENABLE 0        // the switches sit at machine 0, which the plan may reach (see the guide)
#define DEFAULT_INVERT_PROBE_PIN 0
#define DEFAULT_LASER_MODE 0
#define DEFAULT_HOMING_ENABLE 1            // power up locked until $H: an Uno forgets its position at every reset
#define DEFAULT_HOMING_DIR_MASK 0          // home towards + on both arms (switches at the max_deg ends)
#define DEFAULT_HOMING_FEED_RATE 50.0      // locate, deg/min
#define DEFAULT_HOMING_SEEK_RATE 500.0     // seek, deg/min
#define DEFAULT_HOMING_DEBOUNCE_DELAY 250  // ms
#define DEFAULT_HOMING_PULLOFF 1.0         // deg: MPos = -1 after homing

#endif
