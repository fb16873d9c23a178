"""gonio-reconstruct: slices -> full MERL BRDF table (not built yet)."""

from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> int:
    print("gonio-reconstruct: the reconstruction methods are not built yet (issue 5); nothing was written.",
          file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
