"""The noise estimate of :func:`dtalign.products.estimate_noise_sigma`, compiled.

Its specification is :func:`dtalign.reference.estimate_noise_sigma`: SciPy's
convolution with Immerkaer's kernel, then two NumPy medians of about a
million values. Here the filter writes the interior responses in one pass
(summed in SciPy's order, so they are bit-identical), and each median is
an exact selection: a sorted stride sample of the values brackets the
wanted ranks, one pass counts the values below the bracket and gathers
those inside it (a few percent of them), and a quickselect of the gathered
values finishes. When the bracket misses (adversarial value orders), the
quickselect runs on all the values instead; the result is the same.
"""

from __future__ import annotations

import numpy as np

from .._jit import inline_kernel, kernel

#: Values up to this many are selected directly (a sample would not pay).
DIRECT_SELECT_MAX = 16384

#: Sample size of the bracket: its sort costs ~0.3 ms, and the bracket of
#: ``+-BRACKET_SIGMAS`` sample standard deviations then holds ~9 % of the values.
SAMPLE_SIZE = 4096

#: Bracketing passes over the gathered values before the quickselect takes
#: whatever is left (each pass keeps ~9 % of random values; ties keep more).
MAX_ROUNDS = 4

#: Half-width of the bracket in binomial standard deviations of a sample
#: rank (sqrt(s p (1 - p)) <= 32 for s = 4096): a miss costs a full
#: quickselect, and at 6 sigma it does not happen by chance.
BRACKET_SIGMAS = 6.0


@inline_kernel
def _response(img, i, j):  # pragma: no cover - compiled
    """Immerkaer's response at interior pixel ``(i, j)``, summed as SciPy sums it.

    The nine products are added to 0.0 in the kernel's row-major order, as
    SciPy's ``correlate`` adds them (the kernel is symmetric, so
    ``convolve`` is the same); the weights are powers of two, so every
    product is exact and the sums round alike: bit-identical responses.
    """
    t = 0.0
    t += img[i - 1, j - 1]
    t += -2.0 * img[i - 1, j]
    t += img[i - 1, j + 1]
    t += -2.0 * img[i, j - 1]
    t += 4.0 * img[i, j]
    t += -2.0 * img[i, j + 1]
    t += img[i + 1, j - 1]
    t += -2.0 * img[i + 1, j]
    t += img[i + 1, j + 1]
    return t


@kernel
def immerkaer_interior(img, out):  # pragma: no cover - compiled
    """Immerkaer's response at every interior pixel, row by row.

    ``out[(i - 1) * (W - 2) + (j - 1)]`` for ``1 <= i < H - 1``,
    ``1 <= j < W - 1``.
    """
    h, w = img.shape
    k = 0
    for i in range(1, h - 1):
        for j in range(1, w - 1):
            out[k] = _response(img, i, j)
            k += 1


@kernel
def _quickselect(a, lo, hi, k):  # pragma: no cover - compiled
    """Reorder ``a[lo:hi]`` so that ``a[k]`` is its element of rank ``k - lo``.

    Elements left of ``k`` are ``<= a[k]``, right of it ``>= a[k]``
    (Hoare partition around the median of three).
    """
    hi -= 1
    while hi > lo:
        mid = (lo + hi) // 2
        # median of three into a[mid]
        if a[mid] < a[lo]:
            a[mid], a[lo] = a[lo], a[mid]
        if a[hi] < a[lo]:
            a[hi], a[lo] = a[lo], a[hi]
        if a[hi] < a[mid]:
            a[hi], a[mid] = a[mid], a[hi]
        pivot = a[mid]
        i = lo
        j = hi
        while i <= j:
            while a[i] < pivot:
                i += 1
            while a[j] > pivot:
                j -= 1
            if i <= j:
                a[i], a[j] = a[j], a[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            return


@kernel
def _ranks_of_all(a, n, k0, k1):  # pragma: no cover - compiled
    """Elements of rank ``k0`` and ``k1 = k0`` or ``k0 + 1`` of ``a[:n]`` (reordered)."""
    _quickselect(a, 0, n, k0)
    lo = a[k0]
    if k1 == k0:
        return lo, lo
    hi = a[k0 + 1]
    for i in range(k0 + 2, n):
        if a[i] < hi:
            hi = a[i]
    return lo, hi


@kernel
def _value(x, i, centre, deviations):  # pragma: no cover - compiled
    """``x[i]``, or ``abs(x[i] - centre)`` when selecting deviations."""
    if deviations:
        return abs(x[i] - centre)
    return x[i]


@kernel
def _gather(x, n, k0, k1, centre, deviations, work):  # pragma: no cover - compiled
    """One bracketing pass over the first ``n`` values (see :func:`_order_pair`).

    Returns ``(m, below, ok)``: ``work[:m]`` holds the values inside a
    bracket drawn from a stride sample, ``below`` values lie under it, and
    ``ok`` says whether ranks ``k0..k1`` fall inside. ``work`` may be ``x``
    itself (the pass writes behind where it reads).
    """
    s = SAMPLE_SIZE
    sample = np.empty(s)
    stride = n / s
    for j in range(s):
        sample[j] = _value(x, int(j * stride), centre, deviations)
    sample.sort()
    half = BRACKET_SIGMAS * np.sqrt(s * 0.25) + 1.0
    i_lo = int(k0 / n * s - half)
    i_hi = int(k1 / n * s + half) + 1
    if i_lo < 0 or i_hi >= s:
        return 0, 0, False
    lo_v = sample[i_lo]
    hi_v = sample[i_hi]
    below = 0
    m = 0
    # branch-free: which side of the bracket a value falls is a coin toss,
    # and a mispredicted branch per value tripled the pass
    for i in range(n):
        v = _value(x, i, centre, deviations)
        below += v < lo_v
        work[m] = v
        m += (v >= lo_v) & (v <= hi_v)
    return m, below, below <= k0 and k1 < below + m


@kernel
def _order_pair(x, k0, k1, centre, deviations, work):  # pragma: no cover - compiled
    """Elements of rank ``k0`` and ``k1`` (``k0`` or ``k0 + 1``) of the values.

    The values are ``x`` or, with ``deviations``, ``abs(x - centre)``
    (computed exactly as NumPy computes ``np.abs(x - centre)``); ``x`` is
    not modified, ``work`` (as long as ``x``) is scratch. Bracketing passes
    shrink the candidates to at most :data:`DIRECT_SELECT_MAX` (two passes
    for a million values), then a quickselect finishes.
    """
    n = x.shape[0]
    m = n
    below = 0
    ok = False
    if n > DIRECT_SELECT_MAX:
        m, below, ok = _gather(x, n, k0, k1, centre, deviations, work)
    if not ok:
        for i in range(n):
            work[i] = _value(x, i, centre, deviations)
        m = n
        below = 0
    rounds = 0
    while m > DIRECT_SELECT_MAX and rounds < MAX_ROUNDS:
        rounds += 1
        m2, b2, ok = _gather(work, m, k0 - below, k1 - below, 0.0, False, work)
        if ok and m2 == m:  # ties: the bracket is one value; select among them
            break
        if not ok:
            # the gathered values were overwritten only by themselves: redo
            # the selection on all the values
            for i in range(n):
                work[i] = _value(x, i, centre, deviations)
            m = n
            below = 0
            break
        m = m2
        below += b2
    return _ranks_of_all(work, m, k0 - below, k1 - below)


@kernel
def noise_statistics(img):  # pragma: no cover - compiled
    """``(median, mad, mean_abs)`` of Immerkaer's interior responses (H, W >= 3).

    ``median`` and ``mad`` equal ``np.median(f)`` and
    ``np.median(np.abs(f - median))`` exactly (the middle element, or the
    mean of the two middle ones as ``(a + b) / 2``); ``mean_abs`` is
    ``mean(abs(f))`` (compensated sum), computed only when ``mad`` is 0.
    """
    h, w = img.shape
    n = (h - 2) * (w - 2)
    f = np.empty(n)
    work = np.empty(n)
    k1 = n // 2
    k0 = k1 if n % 2 else k1 - 1
    immerkaer_interior(img, f)
    a, b = _order_pair(f, k0, k1, 0.0, False, work)
    centre = a if k0 == k1 else (a + b) / 2.0
    a, b = _order_pair(f, k0, k1, centre, True, work)
    mad = a if k0 == k1 else (a + b) / 2.0
    mean_abs = 0.0
    if not mad > 0.0:
        # Neumaier's compensated sum: within an ulp or two of NumPy's pairwise one
        total = 0.0
        comp = 0.0
        for i in range(n):
            v = abs(f[i])
            t = total + v
            if abs(total) >= v:
                comp += (total - t) + v
            else:
                comp += (v - t) + total
            total = t
        mean_abs = (total + comp) / n
    return centre, mad, mean_abs
