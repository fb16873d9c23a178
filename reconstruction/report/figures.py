"""Matplotlib for the HTML report's figures (:mod:`reconstruction.report.html`), drawn cheaply with the same look:
figures outside pyplot, axes placed by fixed margins instead of ``tight_layout``, log tick labels as plain text
instead of mathtext, PNGs at a fast zlib level; :func:`warm_up`, the imports and the font, which a helper thread
does while the reconstruction finishes; and :func:`beside`, figures drawn in a forked child process while this
one draws others (matplotlib holds the GIL: a thread would not draw beside it). Matplotlib is imported when first
used."""

from __future__ import annotations

import base64
import io
import json
import os
import sys
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["DPI", "PNG_COMPRESS_LEVEL", "png", "figure", "margins", "plain", "plain_log_ticks", "warm_up", "beside",
           "can_fork"]

#: the figures' resolution (dots per inch) and their PNGs' zlib level (1: files about 15 % larger than at PIL's
#: default 6, written several times faster)
DPI = 90
PNG_COMPRESS_LEVEL = 1


def png(fig: Any) -> str:
    """A matplotlib figure as an inline data URI (PNG)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, pil_kwargs={"compress_level": PNG_COMPRESS_LEVEL})
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def figure(figsize: tuple[float, float]) -> Any:
    """A matplotlib figure of ``figsize`` (inches) outside pyplot (no global state: nothing to close, and any
    thread may draw one), rendered by Agg when saved."""
    from matplotlib.figure import Figure

    return Figure(figsize=figsize)


def margins(fig: Any, left: float, right: float, bottom: float, top: float, wgap: float = 0.0,
             hgap: float = 0.0) -> None:
    """Place the figure's grid of axes by fixed margins and gaps between panels, all in inches (what
    ``tight_layout`` found for the demo's figures, with room for wider tick labels): no measuring of every text,
    which cost a third of the page's drawing."""
    w, h = fig.get_size_inches()
    gs = fig.axes[0].get_gridspec() if fig.axes else None
    rows, cols = (gs.nrows, gs.ncols) if gs is not None else (1, 1)
    aw = (w - left - right - (cols - 1) * wgap) / cols  # one panel's width and height (inches)
    ah = (h - bottom - top - (rows - 1) * hgap) / rows
    fig.subplots_adjust(left=left / w, right=1.0 - right / w, bottom=bottom / h, top=1.0 - top / h,
                        wspace=wgap / aw if cols > 1 else 0.0, hspace=hgap / ah if rows > 1 else 0.0)


_SUPERSCRIPT = str.maketrans("0123456789-", "\u2070\u00b9\u00b2\u00b3\u2074\u2075\u2076\u2077\u2078\u2079\u207b")


def plain(label: str) -> str:
    """A log axis's mathtext tick label (``$\\mathdefault{2\\times10^{-1}}$``) as plain text with Unicode
    superscripts (2\u00d710\u207b\u00b9): drawn the same without the mathtext parser."""
    if not (label.startswith("$\\mathdefault{") and label.endswith("}$")):
        return label
    body = label[len("$\\mathdefault{"):-2].replace("\\times", "\u00d7").replace("-", "\u2212")
    head, sep, exp = body.partition("^{")
    return head + (exp.rstrip("}").replace("\u2212", "-").translate(_SUPERSCRIPT) if sep else "")


def plain_log_ticks(axis: Any) -> None:
    """The log ``axis``'s tick labels (major and minor) as plain text (:func:`plain`), with the same choice of
    which ticks are labelled as matplotlib's own formatter."""
    from matplotlib.ticker import LogFormatterSciNotation

    class Plain(LogFormatterSciNotation):
        def __call__(self, x: float, pos: int | None = None) -> str:
            return plain(super().__call__(x, pos))

    for get, put in ((axis.get_major_formatter, axis.set_major_formatter),
                     (axis.get_minor_formatter, axis.set_minor_formatter)):
        f = get()
        if isinstance(f, LogFormatterSciNotation) and not isinstance(f, Plain):
            put(Plain(f._base, labelOnlyBase=f.labelOnlyBase, minor_thresholds=f.minor_thresholds,
                      linthresh=f._linthresh))


def warm_up() -> None:
    """Import matplotlib's figure, its Agg canvas and the tick formatters, and load the default font (about a
    quarter of a second of one core): what the first figure would otherwise wait for."""
    from matplotlib import font_manager
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: F401 - imported for the first savefig
    from matplotlib.figure import Figure  # noqa: F401 - imported for the first figure
    from matplotlib.ticker import LogFormatterSciNotation  # noqa: F401 - imported for the first log axis

    font_manager.findfont(font_manager.FontProperties())


def can_fork() -> bool:
    """Whether figures may be drawn in a forked child: on Linux (fork is what the standard library's process pools
    use there; macOS's system libraries are not fork-safe), with a second core, unless ``GONIO_HTML_FORK=0``."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return (sys.platform.startswith("linux") and hasattr(os, "fork") and cores > 1
            and os.environ.get("GONIO_HTML_FORK", "1") != "0")


def beside(jobs: Mapping[str, Callable[[], str]]) -> Callable[[], dict[str, str]]:
    """Draw ``jobs`` (name -> a function giving a figure's data URI, :func:`png`) in a forked child process while
    this one goes on; returns a function giving {name: data URI}. The child inherits everything the figures need
    (nothing is pickled) and sends back only the URIs through a pipe, then exits without cleanup
    (``os._exit``). Without fork (:func:`can_fork`), or when the child fails, the figures are drawn here when the
    result is asked for, so that an error is raised in this process as without a child."""

    def here() -> dict[str, str]:
        return {k: f() for k, f in jobs.items()}

    if not jobs or not can_fork():
        return here
    r, w = os.pipe()
    try:
        pid = os.fork()
    except OSError:
        os.close(r)
        os.close(w)
        return here
    if pid == 0:  # the child: draw, send, exit at once (no atexit handlers, no flushing of the parent's buffers)
        code = 1
        try:
            os.close(r)
            data = json.dumps(here()).encode("ascii")
            with os.fdopen(w, "wb") as fh:
                fh.write(data)
            code = 0
        finally:
            os._exit(code)
    os.close(w)

    def result() -> dict[str, str]:
        with os.fdopen(r, "rb") as fh:  # read everything before waiting: the URIs are larger than a pipe's buffer
            data = fh.read()
        _, status = os.waitpid(pid, 0)
        if status == 0:
            try:
                out = json.loads(data)
                if isinstance(out, dict) and set(out) == set(jobs):
                    return out
            except ValueError:
                pass
        return here()

    return result
