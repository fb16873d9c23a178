"""The processes and threads that work beside one reconstruction run (:func:`reconstruction.pipeline.run`): the
HTML page's drawer and auto's child, forked as the run starts; the helper threads of the posterior and the page's
sphere renders; one BLAS thread for the run; the shared cone integrals of its fits. The pipeline's steps ask
:class:`Workers` for them and know nothing of forks, thread pools or thread limits (:mod:`reconstruction.executor`
holds the general machinery: :class:`~reconstruction.executor.Forked`, :class:`~reconstruction.executor.Background`,
:class:`~reconstruction.executor.SpareCore`)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass
from typing import Any, TypeVar

from threadpoolctl import threadpool_limits

from reconstruction.executor import Background, Forked, SpareCore
from reconstruction.instrument.response import seed_shared_cone_averages, shared_cone_averages
from reconstruction.job import Job
from reconstruction.methods.auto import KEEP_BUILDS, import_methods, start_child
from reconstruction.report.figures import Drawer

T = TypeVar("T")

__all__ = ["Workers"]


@dataclass(frozen=True)
class Workers:
    """What runs beside one run: ``drawer``, the page's figures drawn in a forked child
    (:class:`~reconstruction.report.figures.Drawer`); ``helper``, a thread for the built-in family's posterior
    beside the reconstruction (and auto's bound from it); ``renders``, a thread for the page's sphere renders.
    Each does its work here, when asked for, where it has no second core or is not wanted."""

    job: Job
    drawer: Drawer
    helper: Background
    renders: Background

    @classmethod
    @contextmanager
    def start(cls, job: Job) -> Iterator[Workers]:
        """The run's workers, ended (children killed and waited for, threads joined) when the block ends.

        The page's drawer and auto's child for the cross-validation of the methods that do not wait for fit first:
        they are forked before any thread of the run starts and before scipy is imported (half a second): the
        drawer imports matplotlib meanwhile, auto's child computes fit's cone tables of the samples and imports the
        methods. With the built-in family's posterior beside the reconstruction, one BLAS thread for the whole run,
        so that the limits fit sets and lifts around its own solves (process-wide) never change the posterior's
        threads midway."""
        blas = threadpool_limits(1, user_api="blas") if job.posterior_early else nullcontext()
        with Drawer(enabled=bool(job.html)) as drawer:
            child = Forked(enabled=job.method == "auto")
            seed = (start_child(child, job.inputs, job.quantity, job.columns, job.blind_spot_deg, job.angles_in)
                    if child.alive else None)
            if job.method == "auto":
                import_methods()
            with child, blas, shared_cone_averages(), Background(enabled=job.assesses or job.bounds) as helper, \
                    Background(enabled=bool(job.html)) as renders:
                if seed is not None:
                    seed_shared_cone_averages(seed())
                yield cls(job, drawer, helper, renders)

    @contextmanager
    def reconstructing(self, early: Callable[..., T], *args: Any) -> Iterator[Callable[[], T] | None]:
        """The block of the reconstruction itself: yields the getter of ``early(*args)`` (the built-in family's
        posterior) when the job computes it beside the reconstruction (``Job.posterior_early``), else None.

        auto cross-validates the methods that do not wait for fit beside it (in its forked child, or a thread of its
        own): the posterior waits until that is done (:class:`~reconstruction.executor.SpareCore`: a third busy
        worker on two cores would slow fit, the critical path). With the page, auto's child builds every method
        for it (``KEEP_BUILDS``)."""
        spare = SpareCore(hold=self.job.method == "auto")
        got = self.helper.submit(spare.later(early), *args) if self.job.posterior_early else None
        keep = KEEP_BUILDS.set(bool(self.job.html))  # the page draws every method: auto's child builds its own
        try:
            with spare:
                yield got
        finally:
            KEEP_BUILDS.reset(keep)
