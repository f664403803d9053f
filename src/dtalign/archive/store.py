"""The results store: a folder of Parquet part files, written atomically.

Layout::

    STORE/
      results/part-<ns>-<token>.parquet    one row per fitted polyline
      failures/part-<ns>-<token>.parquet   one row per failed attempt at an item
      .lock                                held (flock) while a run writes

Every write is a new part file, written under a temporary name that starts
with ``.`` (which Parquet readers skip), flushed to disk, then renamed into
place with :func:`os.replace`, which is atomic: a reader, or a run that
crashed half-way, sees each part whole or not at all. A part holds whole
items (every polyline of an image, or its failure), so an item is either
done or not, never half done. Parts are never rewritten or deleted.

An item is **done** when it has result rows, **failed** when it has failure
rows and no result rows (a later successful retry leaves the old failure
rows in place: they are the history), and **missing** otherwise.

The folders read directly with pyarrow or pandas
(``pandas.read_parquet("STORE/results")``); :meth:`Store.results` and
:meth:`Store.failures` return :class:`pyarrow.Table` s.

This module needs pyarrow (``pip install "dtalign[dask]"``) and imports it
when a store is opened; it never imports Dask.
"""

from __future__ import annotations

import contextlib
import os
import time
import uuid
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

__all__ = ["FAILURE_COLUMNS", "RESULT_COLUMNS", "Store", "failure_schema", "result_schema"]

PathLike = str | os.PathLike[str]

#: Result columns: name, pyarrow type name, description (the docs' schema table).
RESULT_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("item_id", "string", "the manifest item (one image)"),
    ("image", "string", "the image path as the manifest writes it"),
    ("polyline", "string", "the polyline path as the manifest writes it"),
    ("polyline_index", "int32", "position of the polyline in the item's list"),
    ("offset_v", "float64", "fitted offset dv, px"),
    ("offset_u", "float64", "fitted offset du, px"),
    ("rotation_rad", "float64", "fitted rotation (0 when not fitted)"),
    ("sigma_v", "float64", "one-sigma of dv (sqrt of cov_vv)"),
    ("sigma_u", "float64", "one-sigma of du"),
    ("sigma_rotation_rad", "float64", "one-sigma of the rotation; null when not fitted"),
    ("cov_vv", "float64", "pose covariance entries (the fit's covariance: the noise measured plus the edge model's floor)"),
    ("cov_vu", "float64", ""),
    ("cov_uu", "float64", ""),
    ("cov_vr", "float64", "rotation entries: null when the rotation is not fitted"),
    ("cov_ur", "float64", ""),
    ("cov_rr", "float64", ""),
    ("coarse_dv", "int32", "integer seed of the coarse search"),
    ("coarse_du", "int32", ""),
    ("at_window_edge", "bool", "seed on the search-window boundary"),
    ("converged", "bool", "LM step fell below the tolerance"),
    ("degenerate", "bool", "no vertex kept weight"),
    ("iterations", "int32", "LM iterations"),
    ("rms_px", "float64", "weighted RMS residual of the inliers"),
    ("raw_rms_px", "float64", "RMS residual of the polarity-accepted vertices"),
    ("inlier_count", "int32", "vertices with positive final weight"),
    ("n_vertices", "int32", "vertices of the polyline"),
    ("polarity_rejected_count", "int32", "vertices the polarity test rejected"),
    ("observable_rank", "int32", "pose directions the geometry constrains"),
    ("status", "string", "the fit's status, when the fit result has one (else null)"),
    ("reasons", "list<string>", "the reasons of that status (else null)"),
    ("ambiguity_ratio", "float64",
     "rival basin's cost over the fit's (dtalign.pipeline.hypotheses; null when not examined)"),
    ("rival_offset_v", "float64", "that rival basin's fitted offset (null when none)"),
    ("rival_offset_u", "float64", ""),
    ("dt_offset_v", "float64",
     "the DT-LM offset (equals offset_v/u unless an edge-profile refinement was accepted "
     "or a second edge's pull corrected it)"),
    ("dt_offset_u", "float64", ""),
    ("profile_accepted", "bool", "the edge-profile refinement was kept (null: no profile)"),
    ("profile_psf_sigma_px", "float64", "its PSF sigma, given or estimated (null: no profile)"),
    ("profile_walk_px", "float64", "its distance from the DT-LM offset (null: no profile)"),
    ("edge_kind", "string", "the declared edge kind, or the profile's edge (null: not declared)"),
    ("noise_sigma", "float64", "noise sigma used (given or estimated)"),
    ("noise_sigma_estimated", "bool", "the noise sigma was estimated from the image"),
    ("fit_rotation", "bool", "the rotation was fitted"),
    ("window_v", "int32", "coarse-search margin"),
    ("window_u", "int32", ""),
    ("read_s", "float64", "item: reading the image and polylines, s"),
    ("prepare_s", "float64", "item: image products (noise, gradient, DT), s"),
    ("fit_s", "float64", "this polyline's coarse search and LM, s"),
    ("item_s", "float64", "item: the whole task on the worker, s"),
    ("polyline_s", "float64", "this polyline's cost: its share of the item's reading and "
     "products (read_s + prepare_s over the item's polylines) plus fit_s, s"),
    ("region_fraction", "float64", "the fraction of the frame the image products covered "
     "(1: the whole frame; dtalign.pipeline.region)"),
    ("worker", "string", "the worker that ran the task"),
    ("dtalign_version", "string", "dtalign version on the worker"),
    ("item_fingerprint", "string", "hash of the item's files, noise, window and options"),
    ("run_id", "string", "the run that wrote the row"),
    ("finished_at", "timestamp", "UTC time the task finished"),
)

#: Failure columns, as :data:`RESULT_COLUMNS`.
FAILURE_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("item_id", "string", "the manifest item"),
    ("image", "string", "the image path as the manifest writes it"),
    ("polylines", "list<string>", "the polyline paths"),
    ("stage", "string", "read, prepare, fit, or worker (the task never returned)"),
    ("error_type", "string", "exception class, e.g. ValueError, FileNotFoundError, KilledWorker"),
    ("error", "string", "the error message (names the file or polyline)"),
    ("worker", "string", "the worker that ran the task (null when unknown)"),
    ("dtalign_version", "string", "dtalign version on the worker (null when unknown)"),
    ("item_fingerprint", "string", "as in results"),
    ("run_id", "string", "the run that wrote the row"),
    ("failed_at", "timestamp", "UTC time of the failure"),
)

_RESULTS, _FAILURES = "results", "failures"
_PART_PREFIX, _PART_SUFFIX = "part-", ".parquet"
#: Temporary names start with "." so pyarrow's (and pandas') folder readers skip them.
_TMP_PREFIX = ".tmp-"


def _pa() -> Any:
    try:
        import pyarrow
    except ImportError:
        raise ImportError(
            "the results store needs pyarrow: pip install 'dtalign[dask]'"
        ) from None
    return pyarrow


def _schema(columns: Sequence[tuple[str, str, str]]) -> Any:
    pa = _pa()
    types = {
        "string": pa.string(), "int32": pa.int32(), "float64": pa.float64(), "bool": pa.bool_(),
        "list<string>": pa.list_(pa.string()), "timestamp": pa.timestamp("us", tz="UTC"),
    }
    return pa.schema([pa.field(name, types[kind]) for name, kind, _ in columns])


def result_schema() -> Any:
    """The :class:`pyarrow.Schema` of the results table."""
    return _schema(RESULT_COLUMNS)


def failure_schema() -> Any:
    """The :class:`pyarrow.Schema` of the failures table."""
    return _schema(FAILURE_COLUMNS)


class StoreBusyError(RuntimeError):
    """Another process is writing to the store."""


class Store:
    """A campaign's results store (a folder; created when missing).

    Parameters
    ----------
    path : str or path-like
        The store's folder.
    fsync : bool, optional
        Flush each part file (and the folder entry) to disk before it
        counts as written, so a power cut cannot lose a part a run has
        reported as stored. On by default.
    """

    def __init__(self, path: PathLike, *, fsync: bool = True) -> None:
        self.path = Path(path)
        self.fsync = bool(fsync)
        if self.path.exists() and not self.path.is_dir():
            raise ValueError(f"store {self.path} exists and is not a folder")
        for sub in (_RESULTS, _FAILURES):
            (self.path / sub).mkdir(parents=True, exist_ok=True)
        self._schemas = {_RESULTS: result_schema(), _FAILURES: failure_schema()}

    def __repr__(self) -> str:
        return f"Store({str(self.path)!r})"

    # ------------------------------------------------------------------ writing

    @contextlib.contextmanager
    def lock(self) -> Iterator[None]:
        """Hold the store's write lock (one run per store at a time).

        The lock is an advisory ``flock`` on ``STORE/.lock``: the operating
        system drops it when the process ends, however it ends, so a crashed
        run never leaves the store locked. While it is held, temporary files
        of earlier, dead runs are removed. Where ``fcntl`` is missing
        (Windows) nothing is locked.

        Raises
        ------
        StoreBusyError
            If another process holds it.
        """
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not POSIX
            yield
            return
        fh = open(self.path / ".lock", "a+")
        try:
            try:
                fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                raise StoreBusyError(
                    f"store {self.path} is being written by another run (STORE/.lock is held)"
                ) from None
            for sub in (_RESULTS, _FAILURES):
                for tmp in (self.path / sub).glob(_TMP_PREFIX + "*"):
                    tmp.unlink(missing_ok=True)
            yield
        finally:
            fh.close()

    def _write_part(self, sub: str, rows: Sequence[Mapping[str, Any]]) -> Path | None:
        if not rows:
            return None
        pa = _pa()
        import pyarrow.parquet as pq

        table = pa.Table.from_pylist(list(rows), schema=self._schemas[sub])
        folder = self.path / sub
        name = f"{_PART_PREFIX}{time.time_ns():020d}-{uuid.uuid4().hex[:12]}{_PART_SUFFIX}"
        tmp = folder / (_TMP_PREFIX + name)
        try:
            with open(tmp, "wb") as fh:
                pq.write_table(table, fh)
                if self.fsync:
                    fh.flush()
                    os.fsync(fh.fileno())
            os.replace(tmp, folder / name)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
        if self.fsync and hasattr(os, "O_DIRECTORY"):
            fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        return folder / name

    def append(
        self, results: Sequence[Mapping[str, Any]] = (), failures: Sequence[Mapping[str, Any]] = ()
    ) -> None:
        """Write result rows and failure rows, each as one new part file.

        Each call should hold whole items. The result part is written before
        the failure part, so an interruption between the two leaves the
        failures to be redone, not results to be lost.

        Parameters
        ----------
        results, failures : sequence of dict
            Rows with the columns of :data:`RESULT_COLUMNS` /
            :data:`FAILURE_COLUMNS` (missing columns are null).
        """
        self._write_part(_RESULTS, results)
        self._write_part(_FAILURES, failures)

    # ------------------------------------------------------------------ reading

    def parts(self, sub: str = _RESULTS) -> list[Path]:
        """The part files of ``"results"`` or ``"failures"``, in the order written."""
        if sub not in self._schemas:
            raise ValueError(f"sub must be 'results' or 'failures', got {sub!r}")
        return sorted((self.path / sub).glob(_PART_PREFIX + "*" + _PART_SUFFIX))

    def _read(self, sub: str, columns: Sequence[str] | None = None) -> Any:
        schema = self._schemas[sub]
        files = self.parts(sub)
        if not files:
            table = schema.empty_table()
            return table if columns is None else table.select(list(columns))
        import pyarrow.dataset as ds

        return ds.dataset([str(f) for f in files], schema=schema, format="parquet").to_table(
            columns=None if columns is None else list(columns)
        )

    def results(self, columns: Sequence[str] | None = None) -> Any:
        """Every result row, as a :class:`pyarrow.Table` (``.to_pandas()`` for pandas)."""
        return self._read(_RESULTS, columns)

    def failures(self, columns: Sequence[str] | None = None, *, open_only: bool = True) -> Any:
        """Failure rows as a :class:`pyarrow.Table`.

        Parameters
        ----------
        open_only : bool, optional
            Only the items that are still failed (no result rows), the
            default; False gives every failed attempt, retried ones too.
        """
        table = self._read(_FAILURES, columns if columns is None or "item_id" in columns
                           else ["item_id", *columns])
        if open_only and table.num_rows:
            import pyarrow.compute as pc

            done = _pa().array(sorted(self.done_ids()), type=_pa().string())
            table = table.filter(pc.invert(pc.is_in(table["item_id"], value_set=done)))
        if columns is not None and "item_id" not in columns:
            table = table.drop_columns(["item_id"])
        return table

    def done_ids(self) -> set[str]:
        """Ids of the items with result rows."""
        return set(self._read(_RESULTS, ["item_id"])["item_id"].to_pylist())

    def failed_ids(self) -> set[str]:
        """Ids of the items with failure rows and no result rows."""
        return set(self._read(_FAILURES, ["item_id"])["item_id"].to_pylist()) - self.done_ids()

    def fingerprints(self) -> dict[str, str]:
        """``item_id -> item_fingerprint`` of the done items."""
        t = self._read(_RESULTS, ["item_id", "item_fingerprint"])
        return dict(zip(t["item_id"].to_pylist(), t["item_fingerprint"].to_pylist(), strict=True))
