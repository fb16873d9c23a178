"""``reconstruction.models`` is :mod:`reconstruction.core.models` (the same module object):
the import name that the README, examples and lab scripts use."""
import sys

from reconstruction.core import models as _module

sys.modules[__name__] = _module
