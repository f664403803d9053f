"""Numba's on-disk cache for dtalign's kernels, made fault tolerant.

Numba's own cache (``cache=True``) fails hard in two situations a deployed
service meets: an entry that cannot be loaded (a truncated or garbled
``.nbi`` / ``.nbc`` file raises ``UnpicklingError``, ``EOFError`` or an
LLVM parse error in every later process, and flipped bytes in cached machine
code that still unpickle can crash the process or change a result), and no
writable cache folder at all (``RuntimeError: cannot cache function ...: no
locator available``). This module keeps Numba's cache -- same folders, same
file names, Numba's locking-free atomic writes -- through its documented
extension points (a :class:`numba.core.caching.FunctionCache` subclass with
its own locator list and index/data file class), and changes only this:

* Every data file starts with the SHA-256 digest of the pickled entry, and
  the index carries the digest of its own contents; both are checked
  before anything is unpickled or handed to LLVM. An entry that fails the
  check, or fails to load for any other reason, is a cache miss: the kernel
  is recompiled and the entry rewritten. The index records its own format
  version, so entries written by plain Numba (or an older dtalign) are
  stale, not damaged: they are replaced without a warning.
* Where Numba finds no writable folder, an existing folder that already
  holds this kernel's index is used read-only (a cache warmed when an image
  was built); where there is none either, the kernel is compiled in memory
  without caching. A failed write is logged and ignored: the compiled code
  is already in memory.

Each of these is reported once per folder and process with a WARNING on the
``dtalign`` logger (never :func:`warnings.warn`: callers run their tests
with warnings as errors); repeats go to DEBUG. See ``docs/caching.rst`` for
what the checksums do and do not protect.

All this subclasses Numba's cache classes, which are not public API. A
Numba release that renames or drops one of them (:data:`MISSING` lists
what this one lacks) does not stop ``import dtalign``: the kernels then
get Numba's plain ``cache=True``, without checksums or read-only
fallbacks, logged once at WARNING (``tests/test_faults_cache.py`` fails on
such a Numba, so an upgrade that loses the checked cache is noticed).
"""

from __future__ import annotations

import hashlib
import logging
import os
import pickle
import sys
import threading
from typing import Any

import numba

try:
    from numba.core import caching as _nc
except ImportError:  # a Numba without the module: every name below is missing
    _nc = None  # type: ignore[assignment]

logger = logging.getLogger("dtalign")

#: What the checked cache needs of :mod:`numba.core.caching`: each class
#: (under its current or, first, older names) and the methods and class
#: attributes of it that the subclasses below override or call.
REQUIRED: dict[tuple[str, ...], tuple[str, ...]] = {
    ("UserProvidedCacheLocator", "_UserProvidedCacheLocator"): ("get_cache_path", "ensure_cache_path"),
    ("InTreeCacheLocator", "_InTreeCacheLocator"): ("get_cache_path", "ensure_cache_path"),
    ("UserWideCacheLocator", "_UserWideCacheLocator"): ("get_cache_path", "ensure_cache_path"),
    ("IPythonCacheLocator", "_IPythonCacheLocator"): (),
    ("ZipCacheLocator", "_ZipCacheLocator"): (),
    ("CompileResultCacheImpl",): ("_locator_classes",),
    ("IndexDataCacheFile",): (
        "load", "save", "_load_index", "_save_index", "_load_data", "_save_data", "_dump",
        "_open_for_write", "_data_name", "_data_path",
    ),
    ("FunctionCache",): ("_impl_class", "load_overload", "save_overload"),
    ("NullCache",): ("save_overload",),
}

#: Missing pieces, as ``"Class"`` or ``"Class.attribute"``: empty on a
#: supported Numba. Anything here means the plain ``cache=True`` fallback.
MISSING: tuple[str, ...]


def _resolve() -> tuple[dict[str, Any], tuple[str, ...]]:
    """The needed classes by their first name, and what is missing."""
    found: dict[str, Any] = {}
    missing: list[str] = []
    for names, attributes in REQUIRED.items():
        cls = next((c for c in (getattr(_nc, n, None) for n in names) if c is not None), None)
        if cls is None:
            missing.append(" or ".join(names))
            # A stand-in base, so the classes below can still be defined; they
            # are never used (attach_cache falls back to Numba's plain cache).
            cls = type(names[0], (), {})
        else:
            missing += [f"{names[0]}.{a}" for a in attributes if not hasattr(cls, a)]
        found[names[0]] = cls
    return found, tuple(missing)


_found, MISSING = _resolve()
_UserProvidedLocator = _found["UserProvidedCacheLocator"]
_InTreeLocator = _found["InTreeCacheLocator"]
_UserWideLocator = _found["UserWideCacheLocator"]
_IPythonLocator = _found["IPythonCacheLocator"]
_ZipLocator = _found["ZipCacheLocator"]
_CompileResultCacheImpl = _found["CompileResultCacheImpl"]
_IndexDataCacheFile = _found["IndexDataCacheFile"]
_FunctionCache = _found["FunctionCache"]
_NullCache = _found["NullCache"]
del _found

#: Format tag stored in each index beside Numba's version: an index without
#: it (plain Numba, older dtalign) is another format, read as stale.
CACHE_FORMAT = "dtalign-sha256-1"

#: Length of the SHA-256 digest that prefixes each checked payload.
_DIGEST_SIZE = hashlib.sha256().digest_size

#: Logged once per process on the ``dtalign`` logger at INFO when the first
#: kernel is about to compile (a cache miss): from Python, a first call
#: otherwise sits silent for the whole compilation and looks hung.
COMPILE_NOTICE = (
    "compiling dtalign's kernels for first use (about 1-3 minutes, once: the machine code "
    "is then cached on disk; dtalign.warm_up() does it ahead of time) ..."
)

#: Callables given the notice too, while registered (a progress bar's writer).
compile_listeners: list[Any] = []

_announced = False


def announce_compile() -> None:
    """Log :data:`COMPILE_NOTICE` at INFO, the first time in this process only,
    and hand it to each of :data:`compile_listeners`."""
    global _announced
    with _reported_lock:
        if _announced:
            return
        _announced = True
    logger.info("%s", COMPILE_NOTICE)
    for listener in list(compile_listeners):
        try:
            listener(COMPILE_NOTICE)
        except Exception:  # a display's failure must not stop the compile
            logger.debug("compile notice listener %r failed", listener, exc_info=True)


#: (kind, folder) pairs already logged at WARNING in this process.
_reported: set[tuple[str, str]] = set()
_reported_lock = threading.Lock()


def _report(kind: str, folder: str, message: str) -> None:
    """Log ``message`` at WARNING the first time for (kind, folder), then at DEBUG."""
    with _reported_lock:
        first = (kind, folder) not in _reported
        _reported.add((kind, folder))
    if first:
        logger.warning("%s (further cases in this folder are logged at DEBUG)", message)
    else:
        logger.debug("%s", message)


class DamagedCacheEntry(Exception):
    """A cache file whose checksum or format does not match its contents."""


# ---------------------------------------------------------------------------
# Locators: Numba's, then existing read-only folders that hold the index
# ---------------------------------------------------------------------------


class _ReadOnlyIndexMixin:
    """Accept an existing folder this process cannot write to, if it holds
    the function's index file: a cache warmed before the install became
    read-only. Loading works; saving fails and is logged by the cache."""

    _py_file: str
    _lineno: int
    _index_name: str

    def __init__(self, py_func: Any, py_file: str) -> None:
        super().__init__(py_func, py_file)  # type: ignore[call-arg]
        # The index name Numba's CacheImpl gives this function (modname.qualname-lineno.pyXY).
        qualname = getattr(py_func, "__qualname__", py_func.__name__)
        modname = os.path.splitext(os.path.basename(py_file))[0]
        fullname = f"{modname}.{qualname}".replace("<", "").replace(">", "")
        self._index_name = (
            f"{fullname}-{self._lineno}.py{sys.version_info[0]}{sys.version_info[1]}"
            f"{getattr(sys, 'abiflags', '')}.nbi"
        )

    def ensure_cache_path(self) -> None:
        path = self.get_cache_path()  # type: ignore[attr-defined]
        # isfile, not os.access: access() checks the real uid and ignores
        # capabilities, open() does not; an unreadable index fails on load.
        if not os.path.isfile(os.path.join(path, self._index_name)):
            raise OSError(f"no readable cache index in {path}")


class _ReadOnlyUserProvidedLocator(_ReadOnlyIndexMixin, _UserProvidedLocator):  # type: ignore[misc, valid-type]
    """``NUMBA_CACHE_DIR``, read-only, when it holds the index."""


class _ReadOnlyInTreeLocator(_ReadOnlyIndexMixin, _InTreeLocator):  # type: ignore[misc, valid-type]
    """``__pycache__`` beside the source, read-only, when it holds the index."""


class _ReadOnlyUserWideLocator(_ReadOnlyIndexMixin, _UserWideLocator):  # type: ignore[misc, valid-type]
    """Numba's user-wide folder, read-only, when it holds the index."""


class _CacheImpl(_CompileResultCacheImpl):  # type: ignore[misc, valid-type]
    """Numba's compile-result cache with the read-only fallbacks.

    Each read-only locator follows the writable one of the same folder, so
    ``NUMBA_CACHE_DIR`` (writable or pre-warmed) still wins over the
    package folder, and a pre-warmed package folder over the user's home.
    ``NUMBA_CACHE_LOCATOR_CLASSES``, when set, replaces this list as in Numba.
    """

    _locator_classes = [
        _UserProvidedLocator,
        _ReadOnlyUserProvidedLocator,
        _InTreeLocator,
        _ReadOnlyInTreeLocator,
        _UserWideLocator,
        _ReadOnlyUserWideLocator,
        _IPythonLocator,
        _ZipLocator,
    ]


# ---------------------------------------------------------------------------
# Index and data files with checksums
# ---------------------------------------------------------------------------


def _seal(payload: bytes) -> bytes:
    return hashlib.sha256(payload).digest() + payload


def _unseal(raw: bytes, path: str) -> bytes:
    digest, payload = raw[:_DIGEST_SIZE], raw[_DIGEST_SIZE:]
    if len(digest) != _DIGEST_SIZE or hashlib.sha256(payload).digest() != digest:
        raise DamagedCacheEntry(f"{os.path.basename(path)}: checksum mismatch")
    return payload


class _CheckedCacheFile(_IndexDataCacheFile):  # type: ignore[misc, valid-type]
    """Numba's index/data files, each payload prefixed by its SHA-256."""

    def __init__(self, cache_path: str, filename_base: str, source_stamp: Any) -> None:
        super().__init__(cache_path, filename_base, source_stamp)
        self._version = (numba.__version__, CACHE_FORMAT)

    def load(self, key: Any) -> Any:
        """The entry for ``key``, or None (a miss) if it cannot be loaded."""
        try:
            return super().load(key)
        except Exception as exc:  # any damage is a miss; the entry is rewritten
            self._damaged(exc)
            return None

    def save(self, key: Any, data: Any) -> None:
        """Save as Numba does; a damaged index is replaced by a new one."""
        try:
            overloads = self._load_index()
        except Exception as exc:
            self._damaged(exc)
            overloads = {}
        data_name = overloads.get(key)
        if data_name is None:
            existing = set(overloads.values())
            number = 1
            while self._data_name(number) in existing:
                number += 1
            data_name = self._data_name(number)
            overloads[key] = data_name
            self._save_index(overloads)
        self._save_data(data_name, data)

    def _damaged(self, exc: BaseException) -> None:
        _report(
            "damaged",
            self._cache_path,
            f"Numba cache in {self._cache_path}: an entry of {self._index_name} "
            f"cannot be loaded ({type(exc).__name__}: {exc}); recompiling the kernel "
            "and replacing the entry",
        )

    def _load_index(self) -> dict[Any, str]:
        try:
            with open(self._index_path, "rb") as f:
                version = pickle.load(f)
                if version != self._version:
                    return {}  # another format or Numba version: stale, not damaged
                raw = f.read()
        except FileNotFoundError:
            return {}
        stamp, overloads = pickle.loads(_unseal(raw, self._index_path))
        if stamp != self._source_stamp:
            return {}
        if not isinstance(overloads, dict):
            raise DamagedCacheEntry(f"{self._index_name}: not an index")
        return overloads

    def _save_index(self, overloads: dict[Any, str]) -> None:
        payload = self._dump((self._source_stamp, overloads))
        with self._open_for_write(self._index_path) as f:
            pickle.dump(self._version, f, protocol=-1)
            f.write(_seal(payload))

    def _load_data(self, name: str) -> Any:
        path = self._data_path(name)
        with open(path, "rb") as f:
            raw = f.read()
        return pickle.loads(_unseal(raw, path))

    def _save_data(self, name: str, data: Any) -> None:
        payload = self._dump(data)
        with self._open_for_write(self._data_path(name)) as f:
            f.write(_seal(payload))


class CheckedFunctionCache(_FunctionCache):  # type: ignore[misc, valid-type]
    """Numba's per-function cache, with checksummed files and no hard failure.

    Loading: a miss for anything that cannot be loaded (then the dispatcher
    compiles and saves over the entry). Saving: a failure (read-only folder,
    full disk) is logged; the compiled code is used from memory.
    """

    _impl_class = _CacheImpl

    def __init__(self, py_func: Any) -> None:
        super().__init__(py_func)
        self._cache_file = _CheckedCacheFile(
            cache_path=self._cache_path,
            filename_base=self._impl.filename_base,
            source_stamp=self._impl.locator.get_source_stamp(),
        )

    def load_overload(self, sig: Any, target_context: Any) -> Any:
        try:
            data = super().load_overload(sig, target_context)
        except Exception as exc:  # e.g. LLVM cannot parse a bitcode that passed the checksum
            self._cache_file._damaged(exc)
            data = None
        if data is None:  # a miss: Numba compiles next
            announce_compile()
        return data

    def save_overload(self, sig: Any, data: Any) -> None:
        try:
            super().save_overload(sig, data)
        except Exception as exc:
            _report(
                "unwritable",
                self._cache_path,
                f"cannot write the Numba cache in {self._cache_path} "
                f"({type(exc).__name__}: {exc}); the kernel {self._py_func.__qualname__} "
                "is compiled in memory only, and later processes compile it again",
            )


class UncachedFunctionCache(_NullCache):  # type: ignore[misc, valid-type]
    """Numba's in-memory ``NullCache`` that logs when it compiles.

    For a kernel with no usable cache folder. The log comes at the first
    compile, not at decoration: a kernel that is only ever inlined, or
    never called, is not worth a warning.
    """

    def __init__(self, py_func: Any, reason: str) -> None:
        self._py_func = py_func
        self._reason = reason

    def load_overload(self, sig: Any, target_context: Any) -> Any:
        announce_compile()  # nothing to load: every first call compiles
        return None

    def save_overload(self, sig: Any, data: Any) -> None:
        source_dir = os.path.dirname(os.path.abspath(self._py_func.__code__.co_filename))
        _report(
            "nolocator",
            source_dir,
            f"no usable Numba cache folder for the kernels in {source_dir}: "
            f"{os.path.join(source_dir, '__pycache__')} and the user-wide cache folder are "
            "not writable and hold no cache index for "
            f"{self._py_func.__qualname__} (NUMBA_CACHE_DIR: "
            f"{os.environ.get('NUMBA_CACHE_DIR') or 'not set'}); compiling in memory "
            f"without caching, in every process ({self._reason})",
        )


def attach_cache(dispatcher: Any) -> Any:
    """Give a fresh Numba dispatcher the checked on-disk cache, or none.

    Equivalent to Numba's ``cache=True`` (``dispatcher.enable_caching()``)
    with :class:`CheckedFunctionCache`. Where no folder can be used, the
    dispatcher compiles in memory (:class:`UncachedFunctionCache`), logged
    once per source folder at its first compile.
    """
    if not hasattr(dispatcher, "enable_caching"):
        return dispatcher  # NUMBA_DISABLE_JIT: njit returned the Python function
    if MISSING:
        return _plain_cache(dispatcher)
    try:
        dispatcher._cache = CheckedFunctionCache(dispatcher.py_func)
    except RuntimeError as exc:  # Numba: "cannot cache function ...: no locator available"
        dispatcher._cache = UncachedFunctionCache(dispatcher.py_func, str(exc))
    return dispatcher


def _plain_cache(dispatcher: Any) -> Any:
    """Numba's own ``cache=True``, for a Numba that lacks what the checked cache needs."""
    _report(
        "fallback",
        "numba",
        f"Numba {numba.__version__} lacks {', '.join(MISSING)} of numba.core.caching, "
        "which dtalign's checksummed kernel cache builds on; using Numba's plain "
        "cache=True instead (no checksums, no read-only fallback; see docs/caching.rst)",
    )
    try:
        dispatcher.enable_caching()
    except RuntimeError as exc:  # "cannot cache function ...: no locator available"
        _report(
            "nolocator",
            "numba",
            f"no usable Numba cache folder ({exc}); compiling in memory without caching",
        )
    return dispatcher
