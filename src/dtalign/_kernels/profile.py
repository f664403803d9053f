"""The photometric edge-profile refinement, compiled.

Its specification is :mod:`dtalign.reference.profile` (same arithmetic, in
NumPy). The model of one pixel ``p`` near vertex ``k`` (see the profiles
page of the docs): the vertex's 1-D radiance profile ``P_k`` along its unit
normal ``n_k``, blurred by a Gaussian PSF of sigma ``sigma``, averaged over
the square pixel (along ``n_k`` the unit square projects to the trapezoid
``box(|n_v|) * box(|n_u|)``), and read at the pixel's signed distance past
the edge, corrected for the edge's curvature ``kappa_k``::

    s     = (p - x_k - d) . n_k            (distance along the normal)
    tau   = (p - x_k - d) . t_k            (distance along the edge)
    s_eff = s - kappa_k (tau^2 + sigma^2 + 1/12) / 2
    value = b + g * M_k(s_eff; sigma)

``M_k = P_k * G_sigma * box * box``; with the PSF's wings (a fraction ``f``
of the light in a Gaussian of sigma ``sigma_w``), ``(1 - f) M_k(s_eff;
sigma) + f M_k(s_eff_w; sigma_w)``, each read at its own curvature-corrected
distance. The curvature term is the mean shift of
a curved edge over the tangential spread of the pixel's own offset, the PSF
(variance ``sigma^2``) and the pixel box (variance 1/12 along any
direction). The profile ``P_k`` is piecewise linear between its samples;
the Gaussian blur of a piecewise-linear function is exact at the samples
(:func:`hat_gauss_taps`), the box average is exact through the second
antiderivative (:func:`cumulate`, :func:`box_model`). The pose ``d``, the
gain ``g``, the background ``b`` and, when unknown, ``sigma`` and the wings
are fitted by Gauss-Newton with Tukey weights (:func:`refine`). Kernels assume valid
C-contiguous float64 input and never validate.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import inline_kernel, kernel

#: The pixel trapezoid's two projected widths (pixels) are floored at this:
#: with a normal within ~1 deg of an axis one width tends to 0, where the
#: two-box difference divides by the width (0 for an axis-aligned normal,
#: ~1e-16 for one computed as ``cos(pi / 2)``) and loses its digits to
#: cancellation. Floored, the model is one formula, continuous in both
#: widths, in either order; the box it adds has a variance of at most
#: ``MIN_BOX_WIDTH**2 / 12`` (3e-5 px^2), which moves no edge measurably,
#: and the cancellation costs ~1e-11 of the contrast (both widths floored,
#: a 12 px table; tests/test_profile_numerics.py bounds it).
MIN_BOX_WIDTH = 0.02

#: Gaussian taps reach this many sigmas (the mass beyond is < 7e-5 of the
#: total on each side, far below the edge-position budget).
TAPS_SIGMAS = 4.0

#: The residual scale follows the first iterations (the start, off by the
#: DT's bias, has inflated residuals) and is then held: a scale that keeps
#: moving changes the cost under the step test, and the weights of pixels
#: near the cutoff then chase it for tens of iterations.
SCALE_ITERATIONS = 3

#: Parameters of the refinement: dv, du, gain, background, PSF sigma, the
#: amplitude of the profile's optional shape basis, the background's slope
#: along the normal (scattered light: a glow), and the PSF's wings: the
#: fraction of the light in a second, wider Gaussian and its sigma.
N_PARAMS = 9

#: The blur is computed on merged cells once its sigma spans this many of
#: them (see :func:`tables`): the taps then stay few whatever the sigma.
COARSEN_SIGMAS = 3.0

#: The PSF's wide component: its fraction of the light is held in [0, this]
#: (a halo holding more than half the light would be the PSF, not its
#: wings) ...
MAX_WING_FRACTION = 0.5
#: ... and its sigma at least this many times the core's (a wing as narrow
#: as the core is the core: the fraction would then be undetermined) ...
MIN_WING_RATIO = 3.0
#: ... and at least this (pixels; with no core blur, a wing narrower than
#: the pixel box is the box's own business).
MIN_WING_SIGMA_PX = 1.0
#: ... and at most this (pixels): across a strip of +-3.5 px a wider
#: Gaussian is a ramp, which the background slope fits, and its fraction
#: would be undetermined.
MAX_WING_SIGMA_PX = 10.0

#: Step halvings tried before an iteration is declared stuck.
MAX_HALVINGS = 8

#: The Tukey scale is floored at this fraction of the fitted gain, the
#: profile model's own accuracy (pixel sampling, the law, the PSF's shape
#: are good to about a percent of the contrast): on a clean image the
#: residuals are that model error, not outliers, and an unfloored scale
#: would reject exactly the pixels across the edge (whose model error is
#: largest), making the cost depend on where the fit started.
SCALE_FLOOR = 0.01


@kernel
def hat_gauss_taps(sigma: float, h: float) -> np.ndarray:
    """Taps ``k_m = (hat_h * G_sigma)(m h)``: exact Gaussian blur of a piecewise-linear profile."""
    if sigma <= 0.0:
        out = np.ones(1)
        return out
    half = int(math.ceil(TAPS_SIGMAS * sigma / h)) + 1
    out = np.empty(2 * half + 1)
    inv = 1.0 / (sigma * math.sqrt(2.0))
    c = sigma / math.sqrt(2.0 * math.pi)
    for m in range(-half, half + 1):
        acc = 0.0
        for d, wgt in ((-1.0, 1.0), (0.0, -2.0), (1.0, 1.0)):
            x = (m + d) * h
            acc += wgt * (x * 0.5 * (1.0 + math.erf(x * inv)) + c * math.exp(-(x * inv) ** 2))
        out[m + half] = acc / h
    return out


@kernel
def blur_rows(values: np.ndarray, j0: int, nb: int, taps: np.ndarray) -> np.ndarray:
    """Rows of ``values`` convolved with ``taps`` at columns ``j0 .. j0 + nb - 1`` (ends held).

    Each row is first copied with its ends held over the taps' reach, so the
    inner loop runs over the output columns without a bounds test: every
    output sums its taps in the same order as a tap-inner loop (the same
    bits), and the columns, independent, vectorise.
    """
    n, m = values.shape
    nt = taps.shape[0]
    half = (nt - 1) // 2
    out = np.zeros((n, nb))
    ext = np.empty(nb + nt - 1)
    for k in range(n):
        for x in range(nb + nt - 1):
            j = j0 - half + x
            if j < 0:
                j = 0
            elif j > m - 1:
                j = m - 1
            ext[x] = values[k, j]
        row = out[k]
        for t in range(nt):
            tap = taps[t]
            src = ext[nt - 1 - t : nt - 1 - t + nb]
            for i in range(nb):  # 1-D views: the loop vectorises
                row[i] += src[i] * tap
    return out


@kernel
def cumulate(b: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """First and second antiderivatives of each piecewise-linear row, 0 at its first sample."""
    n, nb = b.shape
    c = np.zeros((n, nb))
    d = np.zeros((n, nb))
    for k in range(n):
        for i in range(nb - 1):
            slope = b[k, i + 1] - b[k, i]
            c[k, i + 1] = c[k, i] + h * (b[k, i] + b[k, i + 1]) * 0.5
            d[k, i + 1] = d[k, i] + c[k, i] * h + b[k, i] * h * h * 0.5 + slope * h * h / 6.0
    return c, d


@inline_kernel
def antiderivs(b: np.ndarray, c: np.ndarray, d: np.ndarray, k: int, x: float, h: float
               ) -> tuple[float, float, float, float]:
    """``(D, C, B, B')`` of row ``k`` at ``x`` samples from its start (held flat beyond)."""
    nb = b.shape[1]
    end = (nb - 1) * h
    if not x > 0.0:  # NaN too: no index is formed from it
        v = b[k, 0]
        return v * x * x * 0.5, v * x, v, 0.0
    if x >= end:
        v = b[k, nb - 1]
        t = x - end
        return d[k, nb - 1] + c[k, nb - 1] * t + v * t * t * 0.5, c[k, nb - 1] + v * t, v, 0.0
    i = int(x / h)
    if i > nb - 2:
        i = nb - 2
    t = x - i * h
    slope = (b[k, i + 1] - b[k, i]) / h
    bv = b[k, i] + slope * t
    cv = c[k, i] + b[k, i] * t + slope * t * t * 0.5
    dv = d[k, i] + c[k, i] * t + b[k, i] * t * t * 0.5 + slope * t * t * t / 6.0
    return dv, cv, bv, slope


@inline_kernel
def box_model(b: np.ndarray, c: np.ndarray, d: np.ndarray, k: int, x: float, h: float,
              wa: float, wb: float) -> tuple[float, float, float]:
    """``M, M', M''`` of row ``k`` averaged over ``box(wa) * box(wb)``, at ``x`` samples from its start.

    Both widths are floored at :data:`MIN_BOX_WIDTH` (the pixel's
    projected widths ``|n_v|``, ``|n_u|``: either can be 0).
    """
    wa = max(wa, MIN_BOX_WIDTH)
    wb = max(wb, MIN_BOX_WIDTH)
    c1 = 0.5 * (wa + wb)
    c2 = 0.5 * (wa - wb)
    d1, e1, f1, _ = antiderivs(b, c, d, k, x + c1, h)
    d2, e2, f2, _ = antiderivs(b, c, d, k, x + c2, h)
    d3, e3, f3, _ = antiderivs(b, c, d, k, x - c2, h)
    d4, e4, f4, _ = antiderivs(b, c, d, k, x - c1, h)
    inv = 1.0 / (wa * wb)
    return ((d1 - d2 - d3 + d4) * inv, (e1 - e2 - e3 + e4) * inv, (f1 - f2 - f3 + f4) * inv)


@kernel
def select_pixels(shape_h: int, shape_w: int, verts: np.ndarray, normals: np.ndarray,
                  tau_max: np.ndarray, half_width: float
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixels ``(i, j)`` within ``half_width`` along and ``tau_max[k]`` across each vertex's normal.

    Returns the vertex index and the two pixel indices of each pick, vertex by vertex.
    """
    n = verts.shape[0]
    cap = 0
    for k in range(n):
        r = math.sqrt(half_width * half_width + tau_max[k] * tau_max[k]) + 1.0
        cap += int((2.0 * r + 1.0) ** 2)
    kk = np.empty(cap, dtype=np.int64)
    ii = np.empty(cap, dtype=np.int64)
    jj = np.empty(cap, dtype=np.int64)
    m = 0
    for k in range(n):
        pv, pu = verts[k, 0], verts[k, 1]
        nv, nu = normals[k, 0], normals[k, 1]
        r = math.sqrt(half_width * half_width + tau_max[k] * tau_max[k]) + 1.0
        i0 = max(0, int(math.floor(pv - r)))
        i1 = min(shape_h - 1, int(math.ceil(pv + r)))
        j0 = max(0, int(math.floor(pu - r)))
        j1 = min(shape_w - 1, int(math.ceil(pu + r)))
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                dv = i - pv
                du = j - pu
                s = dv * nv + du * nu
                t = -dv * nu + du * nv
                if abs(s) <= half_width and abs(t) <= tau_max[k]:
                    kk[m] = k
                    ii[m] = i
                    jj[m] = j
                    m += 1
    return kk[:m].copy(), ii[:m].copy(), jj[:m].copy()


@inline_kernel
def component(b: np.ndarray, c: np.ndarray, d: np.ndarray, bs: np.ndarray, cs: np.ndarray,
              ds: np.ndarray, use_shape: bool, k: int, s: float, tau: float, kap: float,
              sigma: float, t0: float, h: float, wa: float, wb: float, amp: float
              ) -> tuple[float, float, float, float]:
    """One Gaussian component's ``M, M', d M / d sigma`` and shape value at a pixel:
    the profile ``P + amp S`` blurred by ``sigma`` (tables ``b, c, d`` and
    ``bs, cs, ds``), box-averaged, read at the curvature-corrected distance."""
    s_eff = s - 0.5 * kap * (tau * tau + (sigma * sigma + 1.0 / 12.0))
    m0, m1, m2 = box_model(b, c, d, k, s_eff - t0, h, wa, wb)
    a0 = 0.0
    if use_shape:
        a0, a1, a2 = box_model(bs, cs, ds, k, s_eff - t0, h, wa, wb)
        m0 += amp * a0
        m1 += amp * a1
        m2 += amp * a2
    # heat equation: dM/dsigma = sigma M''; the curvature shift moves with sigma^2
    return m0, m1, sigma * m2 - kap * sigma * m1, a0


@kernel
def evaluate(obs: np.ndarray, pix_k: np.ndarray, pix_v: np.ndarray, pix_u: np.ndarray,
             verts: np.ndarray, normals: np.ndarray, curv: np.ndarray,
             b: np.ndarray, c: np.ndarray, d: np.ndarray,
             bs: np.ndarray, cs: np.ndarray, ds: np.ndarray, use_shape: bool,
             t0: float, h: float,
             bw: np.ndarray, cw: np.ndarray, dw: np.ndarray,
             bws: np.ndarray, cws: np.ndarray, dws: np.ndarray, use_wings: bool,
             tw0: float, hw: float, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Residuals ``obs - model`` and the model's Jacobian.

    Columns: dv, du, gain, background, sigma, shape amplitude, background
    slope, wing fraction, wing sigma. The profile is ``P + a S`` (``S`` the
    optional shape basis, tables ``bs, cs, ds``); the PSF is ``(1 - f)``
    of a Gaussian of ``sigma`` (tables ``b .. ds``) plus ``f`` of one of the
    wing sigma (tables ``bw .. dws``, read only when ``use_wings``).
    """
    npx = obs.shape[0]
    r = np.empty(npx)
    jac = np.zeros((npx, N_PARAMS))
    dv0, du0, gain, bg, sigma, amp, slope = (params[0], params[1], params[2], params[3],
                                             params[4], params[5], params[6])
    frac, sigma_w = params[7], params[8]
    for q in range(npx):
        k = pix_k[q]
        nv, nu = normals[k, 0], normals[k, 1]
        ev = pix_v[q] - verts[k, 0] - dv0
        eu = pix_u[q] - verts[k, 1] - du0
        s = ev * nv + eu * nu
        tau = -ev * nu + eu * nv
        kap = curv[k]
        m0, m1, ms, a0 = component(b, c, d, bs, cs, ds, use_shape, k, s, tau, kap, sigma, t0, h,
                                   abs(nv), abs(nu), amp)
        if use_wings:
            w0, w1, ws, aw = component(bw, cw, dw, bws, cws, dws, use_shape, k, s, tau, kap,
                                       sigma_w, tw0, hw, abs(nv), abs(nu), amp)
            jac[q, 7] = gain * (w0 - m0)
            jac[q, 8] = gain * frac * ws
            m0 = (1.0 - frac) * m0 + frac * w0
            m1 = (1.0 - frac) * m1 + frac * w1
            ms = (1.0 - frac) * ms
            a0 = (1.0 - frac) * a0 + frac * aw
        r[q] = obs[q] - (bg + slope * s + gain * m0)
        # d s_eff / d(dv, du) = -n + kappa tau t, with t = (-nu, nv)
        gv = -nv - kap * tau * nu
        gu = -nu + kap * tau * nv
        jac[q, 0] = gain * m1 * gv - slope * nv
        jac[q, 1] = gain * m1 * gu - slope * nu
        jac[q, 2] = m0
        jac[q, 3] = 1.0
        jac[q, 4] = gain * ms
        jac[q, 5] = gain * a0
        jac[q, 6] = s
    return r, jac


@inline_kernel
def tukey_rho(x: float) -> float:
    """Tukey's biweight loss of a residual in units of the cutoff (1/6 beyond it)."""
    if abs(x) >= 1.0:
        return 1.0 / 6.0
    u = 1.0 - x * x
    return (1.0 - u * u * u) / 6.0


@kernel
def robust_cost(r: np.ndarray, cs: float) -> float:
    """Sum of :func:`tukey_rho` of the residuals over the cutoff ``cs``."""
    acc = 0.0
    for q in range(r.shape[0]):
        acc += tukey_rho(r[q] / cs)
    return acc


@kernel
def solve_small(a: np.ndarray, rhs: np.ndarray) -> tuple[np.ndarray, bool]:
    """Gaussian elimination with partial pivoting of a small system; False when
    singular or when the solution is not finite."""
    n = rhs.shape[0]
    m = a.copy()
    x = rhs.copy()
    for col in range(n):
        p = col
        for row in range(col + 1, n):
            if abs(m[row, col]) > abs(m[p, col]):
                p = row
        if not abs(m[p, col]) > 0.0:
            return x, False
        if p != col:
            for j in range(n):
                tmp = m[col, j]
                m[col, j] = m[p, j]
                m[p, j] = tmp
            tmp = x[col]
            x[col] = x[p]
            x[p] = tmp
        for row in range(col + 1, n):
            f = m[row, col] / m[col, col]
            for j in range(col, n):
                m[row, j] -= f * m[col, j]
            x[row] -= f * x[col]
    finite = True
    for col in range(n - 1, -1, -1):
        acc = x[col]
        for j in range(col + 1, n):
            acc -= m[col, j] * x[j]
        x[col] = acc / m[col, col]
        finite = finite and math.isfinite(x[col])
    # a solution that overflowed (or a non-finite system) is no step: every
    # later table read and tap count assumes finite parameters
    return x, finite


@kernel
def tables(values: np.ndarray, o0: float, h: float, j0: int, nb: int, sigma: float
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
    """The blurred rows over the table's columns ``j0 .. j0 + nb - 1``, their two
    antiderivatives, the table's first offset and its step.

    A blur wider than :data:`COARSEN_SIGMAS` samples is computed on cells of
    ``f`` samples merged (their means: the integral is kept), with the
    sigma reduced by the variance the coarser piecewise-linear grid adds,
    ``((f h)^2 - h^2) / 4``: the same blurred profile for a fraction of the taps.
    """
    f = 1
    if sigma > 0.0:
        f = max(1, int(sigma / (COARSEN_SIGMAS * h)))
    if f == 1:
        b = blur_rows(values, j0, nb, hat_gauss_taps(sigma, h))
        c, d = cumulate(b, h)
        return b, c, d, o0 + j0 * h, h
    n, m = values.shape
    mc = m // f
    hc = f * h
    oc0 = o0 + 0.5 * (f - 1) * h
    jc0 = j0 // f
    jc1 = min(mc - 1, (j0 + nb - 1) // f + 1)
    s2 = sigma * sigma - 0.25 * (hc * hc - h * h)
    taps = hat_gauss_taps(math.sqrt(max(s2, 0.0)), hc)
    # only the merged cells the taps reach (a clamped read is to cell 0 or
    # mc - 1, which the range then holds): the same sums as merging all
    half = (taps.shape[0] - 1) // 2
    lo = max(0, jc0 - half)
    hi = min(mc - 1, jc1 + half)
    coarse = np.empty((n, hi - lo + 1))
    for k in range(n):
        for jc in range(lo, hi + 1):
            acc = 0.0
            for t in range(f):
                acc += values[k, jc * f + t]
            coarse[k, jc - lo] = acc / f
    b = blur_rows(coarse, jc0 - lo, jc1 - jc0 + 1, taps)
    c, d = cumulate(b, hc)
    return b, c, d, oc0 + jc0 * hc, hc


@kernel
def wing_mixed(rows: np.ndarray, o0: float, h: float, frac: float, sigma_extra: float,
               shift: np.ndarray) -> np.ndarray:
    """``(1 - frac) P + frac (P * G_extra)(x - shift_k)`` of each row ``P``
    on its own grid: the profile whose model under the core Gaussian alone
    is the core-plus-wings one (Gaussians compose; ``shift_k`` is row
    ``k``'s extra curvature shift of the wider component). ``P * G_extra``
    is :func:`tables`' blurred row, linearly interpolated (held beyond its ends)."""
    n, m = rows.shape
    b, _, _, t0, ht = tables(rows, o0, h, 0, m, sigma_extra)
    nb = b.shape[1]
    out = np.empty((n, m))
    for k in range(n):
        for j in range(m):
            wing = b[k, 0]
            if nb > 1:
                pos = (o0 + h * j - shift[k] - t0) / ht
                if pos < 0.0:
                    pos = 0.0
                elif pos > nb - 1.0:
                    pos = nb - 1.0
                i = int(pos)
                if i > nb - 2:
                    i = nb - 2
                t = pos - i
                wing = b[k, i] * (1.0 - t) + b[k, i + 1] * t
            out[k, j] = (1.0 - frac) * rows[k, j] + frac * wing
    return out


@kernel
def hold_bounds(params: np.ndarray, active: np.ndarray, step: np.ndarray, info: np.ndarray,
                grad: np.ndarray) -> bool:
    """Hold the wing parameters that sit on a bound the step pushes past (the
    fraction at 0 or :data:`MAX_WING_FRACTION`, the wing sigma at its least
    or :data:`MAX_WING_SIGMA_PX`):
    their rows of ``info`` and ``grad`` become those of a zero step, in place,
    so the other parameters' step is solved without them (a step clipped at
    the bound afterwards would not be a descent direction). True when any
    was held."""
    n_act = active.shape[0]
    least = max(MIN_WING_RATIO * params[4], MIN_WING_SIGMA_PX)
    held = False
    for a in range(n_act):
        ia = active[a]
        out = ((ia == 7 and ((params[7] <= 0.0 and step[a] < 0.0)
                             or (params[7] >= MAX_WING_FRACTION and step[a] > 0.0)))
               or (ia == 8 and ((params[8] <= least and step[a] < 0.0)
                                or (params[8] >= MAX_WING_SIGMA_PX and step[a] > 0.0))))
        if out:
            for e in range(n_act):
                info[a, e] = 0.0
                info[e, a] = 0.0
            info[a, a] = 1.0
            grad[a] = 0.0
            held = True
    return held


@kernel
def all_tables(values: np.ndarray, shape: np.ndarray, o0: float, h: float, j0: int, nb: int,
               sigma: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                      np.ndarray, float, float]:
    """:func:`tables` of the profile and of its shape basis (the profile's own when it has none)."""
    b, c, d, t0, ht = tables(values, o0, h, j0, nb, sigma)
    if shape.shape[1] > 0:
        bs, cs, ds, _, _ = tables(shape, o0, h, j0, nb, sigma)
        return b, c, d, bs, cs, ds, t0, ht
    return b, c, d, b, c, d, t0, ht


@kernel
def refine(obs: np.ndarray, pix_k: np.ndarray, pix_v: np.ndarray, pix_u: np.ndarray,
           verts: np.ndarray, normals: np.ndarray, curv: np.ndarray, values: np.ndarray,
           shape: np.ndarray, o0: float, h: float, j0: int, nb: int, params0: np.ndarray,
           active: np.ndarray, use_wings: bool, max_iterations: int, tolerance_px: float,
           tukey_c: float) -> tuple[np.ndarray, int, bool, np.ndarray, float, float]:
    """Gauss-Newton with Tukey weights on the ``active`` parameters.

    Parameters are those of :func:`evaluate` (:data:`N_PARAMS`); ``active``
    lists the fitted ones (the others are held). ``shape`` is the shape
    basis, or an empty ``(N, 0)`` array for none. ``use_wings`` adds the
    PSF's wide component (parameters 7 and 8; held at a fraction 0
    otherwise). The sigmas are held >= 0, the wing fraction in
    [0, :data:`MAX_WING_FRACTION`] and the wing sigma at least
    :data:`MIN_WING_RATIO` times the core's and :data:`MIN_WING_SIGMA_PX`,
    at most :data:`MAX_WING_SIGMA_PX`. Returns the parameters, the
    iterations, whether the last full step fell below ``tolerance_px``,
    the inverse information matrix of the active parameters, the residual
    scale (1.4826 MAD, floored) and the final robust cost.
    """
    n_act = active.shape[0]
    use_shape = shape.shape[1] > 0
    params = params0.copy()
    tab = all_tables(values, shape, o0, h, j0, nb, params[4])
    wtab = all_tables(values, shape, o0, h, j0, nb, params[8]) if use_wings else tab
    r, jac = evaluate(obs, pix_k, pix_v, pix_u, verts, normals, curv, tab[0], tab[1], tab[2],
                      tab[3], tab[4], tab[5], use_shape, tab[6], tab[7], wtab[0], wtab[1],
                      wtab[2], wtab[3], wtab[4], wtab[5], use_wings, wtab[6], wtab[7], params)
    converged = False
    iterations = 0
    info = np.zeros((n_act, n_act))
    scale = 0.0
    cost = 0.0
    for it in range(max_iterations):
        iterations = it + 1
        if it < SCALE_ITERATIONS:
            scale = 1.4826 * np.median(np.abs(r))
            floor = SCALE_FLOOR * max(abs(params[2]), 1e-300)
            if scale < floor:
                scale = floor
        cut = tukey_c * scale
        cost = robust_cost(r, cut)
        info[:, :] = 0.0
        grad = np.zeros(n_act)
        for q in range(r.shape[0]):
            x = r[q] / cut
            if abs(x) >= 1.0:
                continue
            w = (1.0 - x * x) ** 2
            for a in range(n_act):
                ja = jac[q, active[a]] * w
                grad[a] += ja * r[q]
                for e in range(a, n_act):
                    info[a, e] += ja * jac[q, active[e]]
        for a in range(n_act):
            for e in range(a):
                info[a, e] = info[e, a]
            if active[a] == 8 and info[a, a] == 0.0:
                # the wing sigma at a wing fraction of 0: no pixel depends on it,
                # so it takes no step instead of making the system singular
                info[a, a] = 1.0
        step, ok = solve_small(info, grad)
        if not ok:
            break
        if use_wings and hold_bounds(params, active, step, info, grad):
            step, ok = solve_small(info, grad)
            if not ok:
                break
        full = 0.0
        for a in range(n_act):
            ia = active[a]
            if ia == 0 or ia == 1 or ia == 4:
                full = max(full, abs(step[a]))
        accepted = False
        for _ in range(MAX_HALVINGS):
            trial = params.copy()
            for a in range(n_act):
                trial[active[a]] += step[a]
            if trial[4] < 0.0:
                trial[4] = 0.0
            if use_wings:
                trial[7] = min(max(trial[7], 0.0), MAX_WING_FRACTION)
                trial[8] = min(max(trial[8], MIN_WING_RATIO * trial[4], MIN_WING_SIGMA_PX),
                               MAX_WING_SIGMA_PX)
            tt = tab
            if trial[4] != params[4]:
                tt = all_tables(values, shape, o0, h, j0, nb, trial[4])
            wt = wtab
            if use_wings and trial[8] != params[8]:
                wt = all_tables(values, shape, o0, h, j0, nb, trial[8])
            rt, jt = evaluate(obs, pix_k, pix_v, pix_u, verts, normals, curv, tt[0], tt[1],
                              tt[2], tt[3], tt[4], tt[5], use_shape, tt[6], tt[7], wt[0], wt[1],
                              wt[2], wt[3], wt[4], wt[5], use_wings, wt[6], wt[7], trial)
            if robust_cost(rt, cut) <= cost:
                params = trial
                tab, wtab, r, jac = tt, wt, rt, jt
                accepted = True
                # judged on the full Gauss-Newton step: a halved one is short by construction
                if full < tolerance_px:
                    converged = True
                break
            for a in range(n_act):
                step[a] *= 0.5
        if not accepted:
            # no step lowers the cost: a minimum when the step has shrunk to nothing
            converged = max(abs(step[0]), abs(step[1])) < tolerance_px
            break
        if converged:
            break
    ident = np.eye(n_act)
    inv = np.zeros((n_act, n_act))
    ok = True
    for a in range(n_act):
        col, good = solve_small(info, ident[:, a].copy())
        ok = ok and good
        inv[:, a] = col
    if not ok:
        inv[:, :] = np.inf
    return params, iterations, converged, inv, scale, cost
