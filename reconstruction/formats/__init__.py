"""File formats: MERL, RGL, Zemax, slice files, generic tables, exports."""
