"""Matplotlib for the HTML report's figures (:mod:`reconstruction.report.html`), drawn cheaply with the same look:
figures outside pyplot, axes placed by fixed margins instead of ``tight_layout``, log tick labels as plain text
instead of mathtext, PNGs at a fast zlib level, minor grid lines of log axes as one collection (:func:`log_grid`);
and :class:`Drawer`, a forked child process that imports matplotlib (:func:`warm_up`) as soon as a run starts
and draws the figures as their data arrive, while the run goes on. Matplotlib is imported when first used."""

from __future__ import annotations

import base64
import io
import json
import os
import pickle
import warnings
from collections.abc import Callable
from typing import Any

from reconstruction.executor import can_fork as fork_ok
from reconstruction.executor import end_child, fork_child, incoming, write_message

__all__ = ["DPI", "PNG_COMPRESS_LEVEL", "png", "figure", "margins", "plain", "plain_log_ticks", "log_grid", "warm_up",
           "Drawer", "can_fork"]

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


#: a log axis spanning at least this many decades gets its minor grid as one line collection instead of ticks
MINOR_AS_LINES_DECADES = 2.0


def log_grid(ax: Any, axis: str = "y", grid: bool = True) -> None:
    """Minor ticks of a log ``axis`` ("x" or "y") of ``ax`` replaced, once the data are plotted and its limits
    settled, by their grid lines drawn as one line collection (with ``grid``; none without), the major grid kept:
    the same look at a fraction of the cost (every minor tick is five artists that matplotlib lays out: about
    40 % of the page's drawing went to ticks). Axes spanning less than :data:`MINOR_AS_LINES_DECADES` keep their
    minor ticks (matplotlib labels some of them there)."""
    import numpy as np
    from matplotlib import rcParams
    from matplotlib.collections import LineCollection
    from matplotlib.ticker import NullLocator

    lo, hi = ax.get_ylim() if axis == "y" else ax.get_xlim()
    lo, hi = min(lo, hi), max(lo, hi)
    if grid:
        ax.grid(True, which="major", axis=axis, alpha=0.2)
    if not (lo > 0 and np.log10(hi / lo) >= MINOR_AS_LINES_DECADES):
        if grid:
            ax.grid(True, which="minor", axis=axis, alpha=0.2)
        return
    (ax.yaxis if axis == "y" else ax.xaxis).set_minor_locator(NullLocator())
    if not grid:
        return
    k = np.arange(np.floor(np.log10(lo)), np.ceil(np.log10(hi)) + 1)
    v = (np.arange(2.0, 10.0)[None, :] * 10.0 ** k[:, None]).ravel()
    v = v[(v > lo) & (v < hi)]
    seg = [[(0.0, y), (1.0, y)] for y in v] if axis == "y" else [[(x, 0.0), (x, 1.0)] for x in v]
    tr = ax.get_yaxis_transform() if axis == "y" else ax.get_xaxis_transform()
    ax.add_collection(LineCollection(seg, transform=tr, colors=rcParams["grid.color"],
                                     linewidths=rcParams["grid.linewidth"], linestyles=rcParams["grid.linestyle"],
                                     alpha=0.2, zorder=0.5), autolim=False)


def warm_up() -> None:
    """Import matplotlib's figure, its Agg canvas and the tick formatters, and load the default font (about a
    quarter of a second of one core): what the first figure would otherwise wait for."""
    from matplotlib import font_manager
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: F401 - imported for the first savefig
    from matplotlib.figure import Figure  # noqa: F401 - imported for the first figure
    from matplotlib.ticker import LogFormatterSciNotation  # noqa: F401 - imported for the first log axis

    font_manager.findfont(font_manager.FontProperties())


def can_fork() -> bool:
    """Whether figures may be drawn in a forked child (:func:`reconstruction.executor.can_fork`), unless
    ``GONIO_HTML_FORK=0``."""
    return fork_ok("GONIO_HTML_FORK")


class Drawer:
    """Figures drawn in a forked child process while this one goes on (matplotlib holds the GIL: a thread would not draw
    beside it). The child is forked when the drawer is made, as early as the run allows (the process is small then,
    and the run's own threads have not started; the child uses none of their locks); it imports matplotlib at once
    (:func:`warm_up`) and draws each figure as soon as :meth:`draw` sends it: a module-level function giving the
    figure's data URI (:func:`png`) and its arguments, pickled (numpy arrays and the samples: kilobytes).
    :meth:`results` gives {name: data URI}: the child sends them all at once when told there is no more, then exits
    without cleanup (``os._exit``). A name sent twice is drawn twice, the last one kept (a figure whose data
    changed). Without fork (:func:`can_fork`, or ``enabled`` False), or when the child fails, the figures are drawn
    here when their results are asked for, so that an error is raised in this process as without a child. A context
    manager: leaving it ends the child (killed if its results were never asked for)."""

    def __init__(self, enabled: bool = True) -> None:
        self.sent: dict[str, tuple[Callable[..., str], tuple[Any, ...]]] = {}
        self._pid = 0
        self._to = self._back = -1
        if enabled and can_fork():
            self._pid, self._to, self._back = fork_child(_child)

    def draw(self, name: str, fn: Callable[..., str], *args: Any) -> None:
        """Send figure ``name``: ``fn(*args)`` gives its data URI (``fn`` a module-level function; ``args``
        picklable)."""
        self.sent[name] = (fn, args)
        if self._to >= 0:
            data = pickle.dumps((name, fn, args), protocol=pickle.HIGHEST_PROTOCOL)
            try:
                write_message(self._to, data)
            except OSError:  # the child is gone: drawn here instead
                self._end()

    def results(self) -> dict[str, str]:
        """Every figure sent: {name: data URI} (those the child did not give, drawn here)."""
        got: dict[str, Any] = {}
        if self._pid:
            os.close(self._to)
            self._to = -1
            with os.fdopen(self._back, "rb") as fh:  # read all before waiting: larger than a pipe's buffer
                self._back = -1
                data = fh.read()
            _, status = os.waitpid(self._pid, 0)
            self._pid = 0
            if status == 0:
                try:
                    got = json.loads(data)
                except ValueError:
                    got = {}
        return {k: got[k] if isinstance(got.get(k), str) else fn(*args) for k, (fn, args) in self.sent.items()}

    def _end(self) -> None:
        end_child(self._pid, self._to, self._back)
        self._pid, self._to, self._back = 0, -1, -1

    def __enter__(self) -> Drawer:
        return self

    def __exit__(self, *exc: object) -> None:
        self._end()


def _child(inbox: int, outbox: int) -> None:
    """The drawer's child: import matplotlib, then draw each figure as it arrives (a thread reads the pipe, so
    the parent's writes never wait for a drawing), and at the end of the input send {name: data URI or None}."""
    code = 1
    try:
        warnings.simplefilter("ignore")
        todo = incoming(inbox)
        warm_up()
        out: dict[str, str | None] = {}
        while (msg := todo.get()) is not None:
            name = "?"
            try:
                name, fn, args = pickle.loads(msg)
                out[name] = fn(*args)
            except Exception:  # noqa: BLE001 - drawn again in the parent, which raises the error there
                out[name] = None
        with os.fdopen(outbox, "wb") as fh:
            fh.write(json.dumps(out).encode("ascii"))
        code = 0
    finally:
        os._exit(code)
