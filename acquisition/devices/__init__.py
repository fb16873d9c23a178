"""Device drivers: each device of a bench behind the protocol the run expects of it (``protocols``).

``protocols`` (what an axis set, a detector and a clock must do: ``typing.Protocol``), ``driver`` (what a driver
declares: its type, section, ports, and how it opens and closes) and ``registry`` (the drivers by type, one line
each); ``dynamixel`` (servo arms through ``dynamixel_sdk``), ``serial_link`` (the detector board and the
text-protocol axes through ``pyserial``), ``grbl`` with ``grbl_settings`` (stepper arms on GRBL 1.1), ``seabreeze``
and ``pm100`` (USB detectors, built by ``external``), ``board`` and ``lines``; ``autorange`` (a detector's
settings stepped down when a reading saturates).
A driver imports the bench file's types, calibration and errors; never a plan, the run, the bench or the CLI.
"""
