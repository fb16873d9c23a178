"""How sure a reconstruction is, and what to measure next: the per-cell uncertainty of a table, the errors to
expect from it (cosl2, image), and the capture advice (:mod:`.uncertainty`, :mod:`.advice`). Above the methods,
below the pipeline: it reads a reconstruction and a prior's posterior, and writes nothing itself."""
