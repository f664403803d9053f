"""Write the offline fallback inventories of the intersphinx links.

``docs/conf.py`` links to the Python, NumPy and SciPy documentation. Sphinx
downloads each project's ``objects.inv`` first; when that fails (no
network), it reads the file written here instead, so ``sphinx -W`` passes
offline and the links the documentation uses still resolve, to the same
URLs. Only the names the documentation refers to are listed: add a line
below (and rerun ``python docs/_intersphinx/make_fallback.py``) when a new
page links to another one.
"""

from __future__ import annotations

import zlib
from pathlib import Path

HERE = Path(__file__).resolve().parent

#: project -> (title, [(name, domain:role, relative uri)]); "$" in a uri is the name.
ENTRIES: dict[str, tuple[str, list[tuple[str, str, str]]]] = {
    "python": (
        "Python",
        [
            ("concurrent.futures", "py:module", "library/concurrent.futures.html#module-$"),
            ("concurrent.futures.ThreadPoolExecutor", "py:class", "library/concurrent.futures.html#$"),
            ("concurrent.futures.ProcessPoolExecutor", "py:class", "library/concurrent.futures.html#$"),
            ("logging", "py:module", "library/logging.html#module-$"),
            ("logging.getLogger", "py:function", "library/logging.html#$"),
            ("warnings.warn", "py:function", "library/warnings.html#$"),
            ("pathlib.Path", "py:class", "library/pathlib.html#$"),
            ("os.replace", "py:function", "library/os.html#$"),
            ("time.perf_counter", "py:function", "library/time.html#$"),
            ("tracemalloc", "py:module", "library/tracemalloc.html#module-$"),
            ("argparse", "py:module", "library/argparse.html#module-$"),
            ("argparse.ArgumentParser", "py:class", "library/argparse.html#$"),
            ("ValueError", "py:exception", "library/exceptions.html#$"),
            ("TypeError", "py:exception", "library/exceptions.html#$"),
            ("ImportError", "py:exception", "library/exceptions.html#$"),
            ("KeyboardInterrupt", "py:exception", "library/exceptions.html#$"),
        ],
    ),
    "numpy": (
        "NumPy",
        [
            ("numpy.ndarray", "py:class", "reference/generated/numpy.ndarray.html#$"),
            ("numpy.typing.ArrayLike", "py:data", "reference/typing.html#$"),
            ("numpy.median", "py:function", "reference/generated/numpy.median.html#$"),
            ("numpy.asarray", "py:function", "reference/generated/numpy.asarray.html#$"),
        ],
    ),
    "scipy": (
        "SciPy",
        [
            ("scipy.linalg.pinvh", "py:function", "reference/generated/scipy.linalg.pinvh.html#$"),
            ("scipy.ndimage.gaussian_filter", "py:function", "reference/generated/scipy.ndimage.gaussian_filter.html#$"),
            ("scipy.ndimage.sobel", "py:function", "reference/generated/scipy.ndimage.sobel.html#$"),
            ("scipy.ndimage.distance_transform_edt", "py:function", "reference/generated/scipy.ndimage.distance_transform_edt.html#$"),
            ("scipy.optimize.OptimizeResult", "py:class", "reference/generated/scipy.optimize.OptimizeResult.html#$"),
            ("scipy.optimize.curve_fit", "py:function", "reference/generated/scipy.optimize.curve_fit.html#$"),
        ],
    ),
    "pyarrow": (
        "Apache Arrow",
        [
            ("pyarrow.Table", "py:class", "python/generated/pyarrow.Table.html#$"),
            ("pyarrow.Schema", "py:class", "python/generated/pyarrow.Schema.html#$"),
        ],
    ),
}


def write(project: str) -> Path:
    title, entries = ENTRIES[project]
    header = (
        "# Sphinx inventory version 2\n"
        f"# Project: {title}\n"
        "# Version: \n"
        "# The remainder of this file is compressed using zlib.\n"
    )
    body = "".join(f"{name} {role} 1 {uri} -\n" for name, role, uri in entries)
    path = HERE / f"{project}.inv"
    path.write_bytes(header.encode() + zlib.compress(body.encode()))
    return path


if __name__ == "__main__":
    for name in ENTRIES:
        print(write(name))
