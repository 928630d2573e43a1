"""numpy's huge pages turned off while a campaign runs (:func:`numpy_huge_pages`).

numpy asks the kernel for transparent huge pages (``madvise(MADV_HUGEPAGE)``) for every array
of 4 MB or more. Where the kernel gives huge pages on request only
(``/sys/kernel/mm/transparent_hugepage/enabled`` set to ``madvise``, a common default), a 47 MP
campaign's pair loop, which allocates and frees frames of 94-188 MB each pair, then held about
1 GB more memory and ran no faster: ``python benches/bench_campaign.py --scales 1.0 --pairs 4
--no-peer --methods II`` on 2 cores (Intel Xeon) peaked at 3074-3099 MB resident with numpy's
default (three runs; 7.2-9.3 pairs/min) and at 2076-2077 MB without its huge pages (three runs;
9.0-9.7 pairs/min) (``benches/RESULTS.md``, thirty-sixth session). The thirty-third session
found the extra resident memory to be anonymous huge pages kept between pairs.

:meth:`rspiv.campaign.runner.Campaign.run` (and :meth:`~rspiv.campaign.runner.Campaign.prepare`
when called on its own) and the Dask executor's tasks therefore turn numpy's request off for
their duration and restore it after: the setting is the process's, so a caller
that runs a campaign from its own program gets its setting back. A user who set numpy's own
environment variable ``NUMPY_MADVISE_HUGEPAGE`` keeps what it says.

The thirty-seventh session found another gigabyte of the same size: what the preparation left
in reference cycles (its backgrounds, target and pilot fields) until Python's collector ran,
now collected when :meth:`~rspiv.campaign.runner.Campaign.prepare` returns. The runs above may
have seen it too; they were not repeated.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

try:  # numpy >= 2
    from numpy._core import multiarray as _multiarray
except ImportError:  # numpy 1.x
    from numpy.core import multiarray as _multiarray  # type: ignore[no-redef]

__all__ = ["numpy_huge_pages"]


@contextlib.contextmanager
def numpy_huge_pages(enabled: bool) -> Iterator[None]:
    """numpy's huge-page request for large arrays set to ``enabled`` inside the block, restored
    after (module docstring). Nothing is changed where numpy has no such setting or the user
    set ``NUMPY_MADVISE_HUGEPAGE``."""
    setter = getattr(_multiarray, "_set_madvise_hugepage", None)
    if setter is None or "NUMPY_MADVISE_HUGEPAGE" in os.environ:
        yield
        return
    before = setter(bool(enabled))
    try:
        yield
    finally:
        setter(before)
