"""Shared fixtures.

``derivatives``: a session-wide cache of image-side products, keyed by the
image's bytes, so tests that share an image compute its gradient and DT
once. The cached arrays are shared: treat them as read-only. (They are not
flagged read-only because Numba would compile a second specialisation of
every kernel for read-only arrays, which callers never pass.)
"""

from __future__ import annotations

import hashlib
from typing import Any

import numpy as np
import pytest


class DerivativeCache:
    """``get(image, noise_sigma)`` -> ``(gradient_magnitude, edge_dt, gradient_vu)``.

    ``reference=True`` (the default) computes them with the NumPy
    specification (``dtalign.reference``), so fitting tests are not
    confounded by the compiled image side; ``reference=False`` uses the
    public ``dtalign`` path.
    """

    def __init__(self) -> None:
        self._store: dict[tuple[Any, ...], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def get(self, image: np.ndarray, noise_sigma: float, *, reference: bool = True
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        arr = np.ascontiguousarray(image, dtype=np.float64)
        key = (hashlib.sha1(arr.tobytes()).hexdigest(), arr.shape, float(noise_sigma), reference)
        if key not in self._store:
            if reference:
                from dtalign.reference import compute_all_image_derivatives
            else:
                from dtalign import compute_all_image_derivatives
            self._store[key] = compute_all_image_derivatives(arr, noise_sigma)
        return self._store[key]


@pytest.fixture(scope="session")
def derivatives() -> DerivativeCache:
    """Session cache of image derivatives (see :class:`DerivativeCache`)."""
    return DerivativeCache()
