"""The run: one capture carried out, recorded and made safe.

``engine`` (carries a plan's messages out against devices that follow ``acquisition.devices.protocols``),
``capture`` (``RunEngine``: the output folder, the bench opened and made safe on every way out, the outcome),
``dryrun`` (the capture's own plan against a dry-run bench: limits and the time model), ``record`` (the typed run
record ``capture.json``), ``outdir``, ``lock``, ``fingerprint`` (same experiment on resume), ``rowcheck`` (the
rows a resume may continue from), ``sliceout`` (the slice written, with each row's check value) and
``interrupts`` (signals). Reaches devices only through their protocols: imports no driver, the bench or the CLI.
"""
