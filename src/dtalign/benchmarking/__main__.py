"""``python -m dtalign.benchmarking``: run the benchmark table (see :func:`main`)."""

from __future__ import annotations

from . import main

if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
