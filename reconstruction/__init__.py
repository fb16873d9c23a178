"""gonio-brdf: reconstruction package.

The import names lab scripts use (``reconstruction.geometry``, ``.models``, ``.merl``, ``.slicefile``) are served
by :mod:`reconstruction.moved` as the modules of ``core/`` and ``formats/`` themselves. Importing the package
registers the MERL file reader that a material's tabulated lobe uses (the core reads no file format itself).
"""

from reconstruction import moved as _moved  # noqa: F401  (registers the old names)
from reconstruction.formats import merl as _merl  # noqa: F401  (registers core.models.TABLE_READER)
