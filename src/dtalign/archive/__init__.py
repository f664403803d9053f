"""Campaigns: fit thousands of images on Dask, resumably, into a Parquet store.

* :mod:`~dtalign.archive.manifest`: the campaign's input, one image per
  record (JSON lines or CSV): :func:`read_manifest`, :class:`Item`;
* :mod:`~dtalign.archive.store`: the results store, Parquet parts written
  atomically (one row per polyline, plus a failures table): :class:`Store`;
* :mod:`~dtalign.archive.runner`: :func:`run`, on a Dask cluster (a new
  LocalCluster, an existing scheduler, or a client you pass);
* :func:`make_example`: a synthetic campaign to try it on.

``dtalign archive MANIFEST --out STORE`` is the command line. Dask and
pyarrow are the optional extra ``dtalign[dask]``; importing this package
imports neither (they load when a run starts or a store is opened), and
the rest of ``dtalign`` never imports them.

Examples
--------
>>> from dtalign import archive                       # doctest: +SKIP
>>> manifest = archive.make_example("campaign")       # doctest: +SKIP
>>> summary = archive.run(manifest, "campaign/store")  # doctest: +SKIP
>>> archive.Store("campaign/store").results().to_pandas()  # doctest: +SKIP
"""

from __future__ import annotations

from .example import make_example
from .manifest import Item, read_manifest, write_manifest
from .runner import RunSummary, local_cluster, run
from .store import Store, StoreBusyError
from .tasks import fit_item

__all__ = [
    "Item",
    "RunSummary",
    "Store",
    "StoreBusyError",
    "fit_item",
    "local_cluster",
    "make_example",
    "read_manifest",
    "run",
    "write_manifest",
]
