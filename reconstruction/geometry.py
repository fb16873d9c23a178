"""``reconstruction.geometry`` is :mod:`reconstruction.core.geometry` (the same module object):
the import name that the README, examples and lab scripts use."""
import sys

from reconstruction.core import geometry as _module

sys.modules[__name__] = _module
