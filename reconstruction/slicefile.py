"""``reconstruction.slicefile`` is :mod:`reconstruction.formats.slicefile` (the same module object):
the import name that the README, examples and lab scripts use."""
import sys

from reconstruction.formats import slicefile as _module

sys.modules[__name__] = _module
