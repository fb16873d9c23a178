"""The virtual devices: what sits behind each port, speaking the real device's bytes.

``dxl_codec`` (Dynamixel Protocol 2.0 packets), ``dxl_servo`` (an X-series servo's control table and motion),
``dxl_device`` (the bus of servos), ``serial_controller`` (the detector board and stepper controller of
docs/serial-protocol.md), ``firmware`` (the detector board's real firmware on an emulated ATmega328P, run by the
simavr harness ``avr_harness.c``). Built on the world (physics, motion, clock, faults); knows no port, study or CLI.
"""
