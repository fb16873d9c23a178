"""gonio-brdf: reconstruction package.

Importing the package registers the MERL file reader that a material's tabulated lobe uses (the core reads no file
format itself).
"""

from reconstruction.formats import merl as _merl  # noqa: F401  (registers core.models.TABLE_READER)
