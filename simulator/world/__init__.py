"""The world the virtual devices live in: ``physics`` (what a detector reads for the arms' positions: signal,
noise, blind spot, collision, saturation; ground-truth materials from ``reconstruction.core.models``), ``motion``
(trapezoidal profiles, backlash, settling), ``clock`` (simulated time) and ``faults``. Imports no device, port,
study or CLI.
"""
