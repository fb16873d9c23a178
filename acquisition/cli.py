"""gonio-capture: drive the bench and capture slices (not built yet)."""

from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> int:
    print("gonio-capture: the acquisition package is not built yet (issue 4); nothing was captured.",
          file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
