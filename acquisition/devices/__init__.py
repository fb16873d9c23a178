"""Device drivers: each device of a bench behind the protocol the run expects of it (``protocols``).

``protocols`` (what an axis set, a detector and a clock must do: ``typing.Protocol``), ``dynamixel`` (servo arms
through ``dynamixel_sdk``), ``serial_link`` (the detector board and the text-protocol axes through ``pyserial``).
A driver imports the bench file's types, calibration and errors; never a plan, the run, the bench or the CLI.
"""
