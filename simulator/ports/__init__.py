"""How the virtual bench is reached: ``transports`` (pseudo-terminals, as a USB adapter appears),
``protocol_sim`` (pyserial's ``sim://`` URL handler, in process) and ``sdk_port`` (the Dynamixel SDK over
``sim://``, for fast in-process tests). Imports the devices, never the study or the CLI.
"""
