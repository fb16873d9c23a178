"""``reconstruction.merl`` is :mod:`reconstruction.formats.merl` (the same module object):
the import name that the README, examples and lab scripts use."""
import sys

from reconstruction.formats import merl as _module

sys.modules[__name__] = _module
