"""The noise estimate of :func:`dtalign.pipeline.products.estimate_noise_sigma`, compiled.

Its specification is :func:`dtalign.reference.estimate_noise_sigma`: SciPy's
convolution with Immerkaer's kernel, then two NumPy medians of about a
million values. Here the responses are computed where they are needed
(summed in SciPy's order, so they are bit-identical), and both medians are
exact selections from one pass over the image (:func:`_one_pass_medians`):
a sorted stride sample of the responses brackets the median and the MAD,
and the pass counts the values below the brackets and gathers those in the
median's bracket and in two bands around ``median -+ MAD`` (a fifth of
them). Bracketing passes over the gathered values then shrink them, and a
quickselect finishes. When a bracket misses (adversarial value orders,
most values tied), the two medians are selected one after the other, each
from a pass of its own, and, should that miss too, from all the values;
the result is the same.
"""

from __future__ import annotations

import numpy as np

from .._jit import inline_kernel, kernel

#: Values up to this many are selected directly (a sample would not pay).
DIRECT_SELECT_MAX = 16384

#: Sample size of the bracket: a larger sample narrows the bracket (as one
#: over its square root) for a longer sort, which at this size stays small
#: beside the pass over the image; the bracket of ``+-BRACKET_SIGMAS``
#: sample standard deviations then holds ~6 % of the values.
SAMPLE_SIZE = 4096

#: Bracketing passes over the gathered values before the quickselect takes
#: whatever is left (each pass keeps ~6 % of random values; ties keep more).
MAX_ROUNDS = 4

#: Half-width of the bracket in binomial standard deviations of a sample
#: rank (sqrt(s p (1 - p)) <= 32 for s = 4096). A miss costs the next,
#: slower selection (same result); at 4 sigma a bracket misses by chance
#: about once in 16,000 calls, and 6 sigma gathered half as many values
#: again, which made the estimate about 10 % slower.
BRACKET_SIGMAS = 4.0

#: How far (as a fraction of the median bracket's half-width) the exact
#: median may lie from the sample's before the one-pass MAD bands start to
#: narrow the MAD's bracket; wider bands gather more values.
CENTRE_TOLERANCE = 1.0 / 3.0

#: The MAD bands' ends are moved off the sampled values by this fraction of
#: the MAD bracket's width (of its value when the bracket is one value): a
#: quantised image's MAD is often one of those values, and a MAD equal to
#: an end's deviation is not selected by the one pass.
BAND_PAD = 1.0 / 16.0


@inline_kernel
def _response(img, i, j):
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
def _row_responses(img, i, row):
    """Immerkaer's responses of interior row ``i`` into ``row`` (``W - 2`` values).

    Each response is :func:`_response`'s sum, in its order; the loop runs
    over the pixels, so LLVM can compute several pixels per vector
    instruction without reordering any pixel's own sum (each is a chain of
    eight dependent adds: one pixel at a time is latency-bound, and the
    more so when a hyperthread sibling shares the core).
    """
    up = img[i - 1]
    mid = img[i]
    dn = img[i + 1]
    for j in range(row.shape[0]):
        t = 0.0
        t += up[j]
        t += -2.0 * up[j + 1]
        t += up[j + 2]
        t += -2.0 * mid[j]
        t += 4.0 * mid[j + 1]
        t += -2.0 * mid[j + 2]
        t += dn[j]
        t += -2.0 * dn[j + 1]
        t += dn[j + 2]
        row[j] = t


@kernel
def immerkaer_interior(img, out):
    """Immerkaer's response at every interior pixel, row by row.

    ``out[(i - 1) * (W - 2) + (j - 1)]`` for ``1 <= i < H - 1``,
    ``1 <= j < W - 1``.
    """
    h, w = img.shape
    wi = w - 2
    for i in range(1, h - 1):
        _row_responses(img, i, out[(i - 1) * wi : i * wi])


@kernel
def _quickselect(a, lo, hi, k):
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
def _ranks_of_all(a, n, k0, k1):
    """Elements of rank ``k0`` and ``k1 = k0`` or ``k0 + 1`` of ``a[:n]`` (reordered)."""
    # a bracket of one value (a quantised image's median, often 0, is a
    # quarter of the pixels): all equal, and a quickselect of ties swaps
    # every one of them (a NaN, from responses that overflowed, is never
    # equal: NumPy's medians then hold NaN, and the quickselect decides)
    first = a[0]
    same = True
    for i in range(1, n):
        if a[i] != first:
            same = False
            break
    if same:
        return first, first
    _quickselect(a, 0, n, k0)
    lo = a[k0]
    if k1 == k0:
        return lo, lo
    hi = a[k0 + 1]
    for i in range(k0 + 2, n):
        if a[i] < hi:
            hi = a[i]
    return lo, hi


@inline_kernel
def _value(x, i, centre, deviations):
    """``x[i]``, or ``abs(x[i] - centre)`` when selecting deviations."""
    if deviations:
        return abs(x[i] - centre)
    return x[i]


@kernel
def _bracket(sample, n, k0, k1):
    """``(found, lo, hi)``: values of a sorted stride sample of ``n`` values
    that bracket ranks ``k0..k1`` with :data:`BRACKET_SIGMAS` to spare."""
    s = sample.shape[0]
    half = BRACKET_SIGMAS * np.sqrt(s * 0.25) + 1.0
    i_lo = int(k0 / n * s - half)
    i_hi = int(k1 / n * s + half) + 1
    if i_lo < 0 or i_hi >= s:
        return False, 0.0, 0.0
    return True, sample[i_lo], sample[i_hi]


@kernel
def _gather(x, n, k0, k1, work):
    """One bracketing pass over ``x[:n]``, in place when ``work`` is ``x``.

    Returns ``(m, below, ok, touched)``: ``work[:m]`` holds the values
    inside a bracket drawn from a stride sample, ``below`` values lie under
    it, ``ok`` says whether ranks ``k0..k1`` fall inside, and ``touched``
    whether ``work`` was written (the pass writes behind where it reads).
    """
    s = SAMPLE_SIZE
    sample = np.empty(s)
    stride = n / s
    for j in range(s):
        sample[j] = x[int(j * stride)]
    sample.sort()
    found, lo_v, hi_v = _bracket(sample, n, k0, k1)
    if not found:
        return 0, 0, False, False
    below = 0
    m = 0
    # branch-free: which side of the bracket a value falls is a coin toss,
    # and a mispredicted branch per value tripled the pass
    for i in range(n):
        v = x[i]
        below += v < lo_v
        work[m] = v
        m += (v >= lo_v) & (v <= hi_v)
    return m, below, below <= k0 and k1 < below + m, True


@kernel
def _sample_responses(img):
    """:data:`SAMPLE_SIZE` responses at evenly strided pixels (``n > SAMPLE_SIZE``).

    Drawn once per estimate and shared by both medians: each sampled pixel
    is three cache misses into the image, ~12k of them, a sizeable part of
    a pass when the memory is shared with other processes.
    """
    h, w = img.shape
    wi = w - 2
    n = (h - 2) * wi
    s = SAMPLE_SIZE
    sample = np.empty(s)
    stride = n / s
    for j in range(s):
        idx = int(j * stride)
        sample[j] = _response(img, idx // wi + 1, idx % wi + 1)
    return sample


@kernel
def _gather_image(img, k0, k1, centre, deviations, work, responses):
    """:func:`_gather` of the image's responses (or their deviations), computed
    a row at a time: no array of a million responses is written and read
    back. ``work`` must hold as many values as the image has responses;
    ``responses`` is :func:`_sample_responses` of the image.
    """
    h, w = img.shape
    wi = w - 2
    n = (h - 2) * wi
    s = responses.shape[0]
    sample = np.empty(s)
    for j in range(s):
        sample[j] = abs(responses[j] - centre) if deviations else responses[j]
    sample.sort()
    found, lo_v, hi_v = _bracket(sample, n, k0, k1)
    if not found:
        return 0, 0, False
    below = 0
    m = 0
    row = np.empty(wi)
    for i in range(1, h - 1):
        _row_responses(img, i, row)
        if deviations:
            for j in range(wi):
                row[j] = abs(row[j] - centre)
        # the count vectorises on its own; the gather is a chain through m
        b = 0
        for j in range(wi):
            b += row[j] < lo_v
        below += b
        for j in range(wi):
            v = row[j]
            work[m] = v
            m += (v >= lo_v) & (v <= hi_v)
    return m, below, below <= k0 and k1 < below + m


@kernel
def _refine(work, m, below, k0, k1):
    """Ranks ``k0, k1`` of all the values, ``work[:m]`` holding those of ranks
    ``below ..``: bracketing passes in place down to :data:`DIRECT_SELECT_MAX`
    values, then a quickselect. Returns ``(ok, a, b)``; ``ok`` is False when
    a pass missed after overwriting ``work`` (start again from all values)."""
    rounds = 0
    while m > DIRECT_SELECT_MAX and rounds < MAX_ROUNDS:
        rounds += 1
        m2, b2, ok, touched = _gather(work, m, k0 - below, k1 - below, work)
        if not ok:
            if touched:
                return False, 0.0, 0.0
            break  # the sample's bracket left the sample: select among all m
        if m2 == m:  # ties: the bracket is one value; select among them
            break
        m = m2
        below += b2
    a, b = _ranks_of_all(work, m, k0 - below, k1 - below)
    return True, a, b


@kernel
def _order_pair(x, k0, k1, centre, deviations, work):
    """Elements of rank ``k0`` and ``k1`` (``k0`` or ``k0 + 1``) of the values.

    The values are ``x`` or, with ``deviations``, ``abs(x - centre)``;
    ``x`` is not modified, ``work`` (as long as ``x``) is scratch.
    """
    n = x.shape[0]
    for i in range(n):
        work[i] = _value(x, i, centre, deviations)
    ok, a, b = _refine(work, n, 0, k0, k1)
    if not ok:
        for i in range(n):
            work[i] = _value(x, i, centre, deviations)
        a, b = _ranks_of_all(work, n, k0, k1)
    return a, b


@kernel
def _image_order_pair(img, k0, k1, centre, deviations, responses):
    """:func:`_order_pair` of the image's responses (or their deviations).

    One bracketing pass over the image gathers ~6 % of the values; only
    when that misses are all the values written out and selected.
    """
    h, w = img.shape
    n = (h - 2) * (w - 2)
    # (as long as all the values, but only the gathered ~6 % are written:
    # the rest of the pages are never touched)
    work = np.empty(n)
    if n > DIRECT_SELECT_MAX:
        m, below, ok = _gather_image(img, k0, k1, centre, deviations, work, responses)
        if ok:
            ok, a, b = _refine(work, m, below, k0, k1)
            if ok:
                return a, b
    immerkaer_interior(img, work)
    if deviations:
        for k in range(n):
            work[k] = abs(work[k] - centre)
    return _ranks_of_all(work, n, k0, k1)


@kernel
def _sorted_deviations(sample, centre):
    """``np.sort(np.abs(sample - centre))`` of a sorted ``sample``, by a merge.

    Left of ``centre`` the deviations fall as the values rise, right of it
    they rise (rounding is monotone), so the two runs merge in one pass.
    """
    s = sample.shape[0]
    out = np.empty(s)
    right = np.searchsorted(sample, centre)
    left = right - 1
    for k in range(s):
        if left < 0:
            out[k] = sample[right] - centre
            right += 1
        elif right >= s:
            out[k] = centre - sample[left]
            left -= 1
        else:
            dl = centre - sample[left]
            dr = sample[right] - centre
            if dl <= dr:
                out[k] = dl
                left -= 1
            else:
                out[k] = dr
                right += 1
    return out


@kernel
def _one_pass_bounds(responses, n, k0, k1):
    """Value bounds of :func:`_gather_centre_and_bands` from the response sample.

    Returns ``(found, c_lo, c_hi, left_lo, inner_lo, inner_hi, right_hi)``:
    ``[c_lo, c_hi]`` brackets the median as :func:`_gather_image` does;
    ``[left_lo, inner_lo]`` and ``[inner_hi, right_hi]`` are two bands of
    values whose distances from the median bracket the MAD, each widened
    on both sides by :data:`CENTRE_TOLERANCE` of the median bracket's
    half-width (the median is not known yet when they are drawn).
    ``found`` is False when a bracket leaves its sample or the bands would
    reach the median's bracket. Correctness never depends on these values,
    only on the checks after the pass (see :func:`_one_pass_medians`).
    """
    s = responses.shape[0]
    sample = np.sort(responses)
    found, c_lo, c_hi = _bracket(sample, n, k0, k1)
    if not found:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    c_s = sample[s // 2]
    found, d_lo, d_hi = _bracket(_sorted_deviations(sample, c_s), n, k0, k1)
    if not found:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    # the pad keeps the bands' ends off the sampled values: on quantised
    # data a tie of the MAD with an end's deviation would miss
    t = CENTRE_TOLERANCE * max(c_s - c_lo, c_hi - c_s) + BAND_PAD * (
        d_hi - d_lo if d_hi > d_lo else d_lo
    )
    inner_lo = c_s - d_lo + t
    inner_hi = c_s + d_lo - t
    # (False as well when a bound is NaN: responses that overflowed)
    if not (inner_lo < c_lo and c_hi < inner_hi):
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    return True, c_lo, c_hi, c_s - d_hi - t, inner_lo, inner_hi, c_s + d_hi + t


@kernel
def _gather_centre_and_bands(img, bounds, work):
    """One pass over the image's responses for both medians.

    ``bounds`` is :func:`_one_pass_bounds`' ``(c_lo, c_hi, left_lo,
    inner_lo, inner_hi, right_hi)`` with ``[c_lo, c_hi]`` inside
    ``(inner_lo, inner_hi)``. Returns ``(mc, mb, below, inner)``:
    ``work[:mc]`` holds every response in ``[c_lo, c_hi]`` and
    ``work[-mb:]`` every one in ``[left_lo, inner_lo]`` or ``[inner_hi,
    right_hi]`` (disjoint sets, so they fit in one array as long as the
    values); ``below`` responses are under ``c_lo`` and ``inner`` lie
    strictly between ``inner_lo`` and ``inner_hi``.
    """
    c_lo, c_hi, left_lo, inner_lo, inner_hi, right_hi = bounds
    h, w = img.shape
    wi = w - 2
    last = work.shape[0] - 1
    below = 0
    inner = 0
    mc = 0
    mb = 0
    row = np.empty(wi)
    in_centre = np.empty(wi, np.int64)
    in_band = np.empty(wi, np.int64)
    for i in range(1, h - 1):
        _row_responses(img, i, row)
        # the tests vectorise on their own; the two gathers are chains
        # through mc and mb, so they get a loop of their own
        b = 0
        c = 0
        for j in range(wi):
            v = row[j]
            b += v < c_lo
            c += (v > inner_lo) & (v < inner_hi)
            in_centre[j] = (v >= c_lo) & (v <= c_hi)
            in_band[j] = (v >= left_lo) & (v <= right_hi) & ((v <= inner_lo) | (v >= inner_hi))
        below += b
        inner += c
        for j in range(wi):
            # both stores write v: when the free slots of the two ends meet,
            # whichever keeps it keeps the right value
            v = row[j]
            work[mc] = v
            mc += in_centre[j]
            work[last - mb] = v
            mb += in_band[j]
    return mc, mb, below, inner


@kernel
def _one_pass_medians(img, k0, k1, bounds):
    """``(ok, median, mad)`` from a single pass over the image.

    ``bounds`` is :func:`_one_pass_bounds`' ``(c_lo, c_hi, left_lo,
    inner_lo, inner_hi, right_hi)``; any values at all may be given: they
    decide only whether the pass succeeds, never the result. The pass
    (:func:`_gather_centre_and_bands`) keeps the values near the
    median and those in two bands around ``median -+ MAD``. Once the
    median ``c`` is selected from the first, every deviation that matters
    is known, because rounding is monotone: with ``d(x) = |x - c|``
    computed as NumPy computes it, a value strictly inside
    ``(inner_lo, inner_hi)`` has ``d(x) <= max(d(inner_lo), d(inner_hi))``,
    so below ``lo``, the next double up; a value outside both bands has
    ``d(x) >= min(d(left_lo), d(right_hi))``, so above ``hi``, the next
    double down. Every deviation in ``[lo, hi]`` therefore belongs to a
    band value, and every one under ``lo`` to an inner or a band value;
    when ranks ``k0..k1`` fall among the band values in ``[lo, hi]``, the
    MAD is selected from those. ``ok`` is False when a bracket misses
    (the two-pass selection then runs); the result is the same.
    """
    n = (img.shape[0] - 2) * (img.shape[1] - 2)
    c_lo, c_hi, left_lo, inner_lo, inner_hi, right_hi = bounds
    # the argument below needs the bands outside the inner interval, and
    # the pass the median's bracket inside it (False as well when a bound
    # is NaN)
    if not (
        left_lo <= inner_lo
        and inner_lo < c_lo
        and c_lo <= c_hi
        and c_hi < inner_hi
        and inner_hi <= right_hi
    ):
        return False, 0.0, 0.0
    # (as long as all the values; only the gathered ones are written, the
    # rest of the pages are never touched)
    work = np.empty(n)
    mc, mb, below, inner = _gather_centre_and_bands(img, bounds, work)
    if not (below <= k0 and k1 < below + mc):
        return False, 0.0, 0.0
    if c_lo == c_hi:  # a bracket of one value (ties: a quantised image's 0)
        a = b = c_lo
    else:
        ok, a, b = _refine(work, mc, below, k0, k1)  # (within work[:mc])
        if not ok:
            return False, 0.0, 0.0
    centre = a if k0 == k1 else (a + b) / 2.0
    # and the median between the bands' outer ends: a value beyond them
    # is then farther from it than the end is
    if not (left_lo <= centre and centre <= right_hi):
        return False, 0.0, 0.0
    lo = np.nextafter(max(abs(inner_lo - centre), abs(inner_hi - centre)), np.inf)
    hi = np.nextafter(min(abs(left_lo - centre), abs(right_hi - centre)), -np.inf)
    # the band values' deviations, compacted to the front (each written at
    # or before where its value was read)
    below = inner
    md = 0
    for i in range(n - mb, n):
        d = abs(work[i] - centre)
        below += d < lo
        work[md] = d
        md += (d >= lo) & (d <= hi)
    if not (below <= k0 and k1 < below + md):
        return False, 0.0, 0.0
    ok, a, b = _refine(work, md, below, k0, k1)
    if not ok:
        return False, 0.0, 0.0
    return True, centre, a if k0 == k1 else (a + b) / 2.0


@kernel
def noise_statistics(img):
    """``(median, mad, mean_abs)`` of Immerkaer's interior responses (H, W >= 3).

    ``median`` and ``mad`` equal ``np.median(f)`` and
    ``np.median(np.abs(f - median))`` exactly (the middle element, or the
    mean of the two middle ones as ``(a + b) / 2``); ``mean_abs`` is
    ``mean(abs(f))`` (compensated sum), computed only when ``mad`` is 0.
    """
    h, w = img.shape
    n = (h - 2) * (w - 2)
    k1 = n // 2
    k0 = k1 if n % 2 else k1 - 1
    responses = _sample_responses(img) if n > DIRECT_SELECT_MAX else np.empty(0)
    ok = False
    centre = mad = 0.0
    if n > DIRECT_SELECT_MAX:
        found, c_lo, c_hi, left_lo, inner_lo, inner_hi, right_hi = _one_pass_bounds(
            responses, n, k0, k1
        )
        if found:
            bounds = (c_lo, c_hi, left_lo, inner_lo, inner_hi, right_hi)
            ok, centre, mad = _one_pass_medians(img, k0, k1, bounds)
    if not ok:
        a, b = _image_order_pair(img, k0, k1, 0.0, False, responses)
        centre = a if k0 == k1 else (a + b) / 2.0
        a, b = _image_order_pair(img, k0, k1, centre, True, responses)
        mad = a if k0 == k1 else (a + b) / 2.0
    mean_abs = 0.0
    if not mad > 0.0:
        # Neumaier's compensated sum: within an ulp or two of NumPy's pairwise one
        total = 0.0
        comp = 0.0
        row = np.empty(w - 2)
        for i in range(1, h - 1):
            _row_responses(img, i, row)
            for j in range(w - 2):
                v = abs(row[j])
                t = total + v
                if abs(total) >= v:
                    comp += (total - t) + v
                else:
                    comp += (v - t) + total
                total = t
        # (an infinite response, from finite pixels near the float range,
        # makes the compensation NaN; NumPy's mean is then inf)
        mean_abs = (total + comp) / n if np.isfinite(total) else total / n
    return centre, mad, mean_abs
