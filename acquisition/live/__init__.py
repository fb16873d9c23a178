"""The live view of a running capture (``gonio-capture ... --live``): a page on 127.0.0.1 that draws the slice as it
grows, the time left and the last sample (:mod:`acquisition.live.server`, :mod:`acquisition.live.page`), served by
a child process (:mod:`acquisition.live.view`) that only reads the capture's files. It imports no driver, plan,
run, bench or command line (an import contract of pyproject.toml)."""

from acquisition.live.view import LiveView

__all__ = ["LiveView"]
