"""Seeded parity cases: the compiled path against ``dtalign.reference``.

An *image* is described by an :class:`ImageSpec` (kind, shape, geometry,
noise, seed) and built deterministically by :func:`make_image`; its
derivatives are computed once (by the caller, with the reference) and
shared by every case that uses it. A :class:`ParityCase` holds a polyline
(vertices, normals, sigmas), the coarse-search window, an optional
sub-pixel jitter added to the coarse seed, and the remaining keywords of
``lm_subpixel_refine``.

Families: translation, rotation, trust region, Tikhonov,
ridge on, polarity off, outliers, degenerate (every vertex rejected),
``max_iterations=0``, flat DT, polylines partly outside the image, random
walks that follow no edge, and a handful of 1024 x 1024 scenes. Images
are mostly 96-256 px so the whole sweep stays fast.

Also here: the contract's state of a pose (:func:`spec_state`) and the two
conditioning measures that decide which fits are held to exact parity
(see ``test_parity``'s docstring).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dtalign import reference as ref
from dtalign.scenes import disc_scene, navigation_scene

__all__ = ["AMPLIFICATION_MAX", "IMAGES", "KAPPA_MAX", "ImageSpec", "ParityCase", "build_cases",
           "make_image", "scaled_condition", "spec_state"]


@dataclass(frozen=True)
class ImageSpec:
    """A synthetic image: ``kind`` in disc, nav, blob, square, flat."""

    key: str
    kind: str
    shape: tuple[int, int]
    radius: float
    noise_sigma: float
    seed: int
    centre_frac: tuple[float, float] = (0.5, 0.5)  # blob / square centre


@dataclass(frozen=True)
class ParityCase:
    case_id: str
    family: str
    image: ImageSpec
    vertices: np.ndarray
    normals: np.ndarray
    sigmas: np.ndarray
    window: tuple[int, int]
    jitter: tuple[float, float] = (0.0, 0.0)
    lm_kwargs: dict[str, Any] = field(default_factory=dict)

    @property
    def rotation_scale(self) -> float:
        """Pixels per radian used to express a rotation difference in px."""
        return max(float(self.lm_kwargs.get("pivot_distance_px", 0.0)), 1.0)


def _image_pool() -> dict[str, ImageSpec]:
    rng = np.random.default_rng(20240601)
    pool: list[ImageSpec] = []
    disc_shapes = [(96, 96), (128, 128), (128, 176), (160, 120), (192, 192),
                   (256, 256), (101, 149), (224, 160), (256, 200), (144, 144)]
    for i, shape in enumerate(disc_shapes):
        radius = float(rng.uniform(0.22, 0.36) * min(shape))
        pool.append(ImageSpec(f"disc{i}", "disc", shape, radius,
                              float(rng.uniform(1.0, 4.0)), 100 + i))
    nav_shapes = [(160, 160), (192, 224), (256, 256), (200, 180), (240, 240), (256, 192)]
    for i, shape in enumerate(nav_shapes):
        radius = float(rng.uniform(0.2, 0.27) * min(shape))
        pool.append(ImageSpec(f"nav{i}", "nav", shape, radius,
                              float(rng.uniform(1.0, 3.0)), 200 + i))
    blob_shapes = [(128, 128), (160, 192), (200, 200), (256, 224), (113, 140),
                   (192, 160), (224, 224), (150, 150)]
    for i, shape in enumerate(blob_shapes):
        # the last three sit across the image border: polylines partly outside
        centre = (0.5, 0.5) if i < 5 else [(0.12, 0.5), (0.5, 0.9), (0.85, 0.15)][i - 5]
        radius = float(rng.uniform(0.25, 0.33) * min(shape))
        pool.append(ImageSpec(f"blob{i}", "blob", shape, radius,
                              float(rng.uniform(1.0, 3.0)), 300 + i, centre))
    for i, shape in enumerate([(128, 128), (176, 150), (200, 240), (256, 256)]):
        radius = float(rng.uniform(0.2, 0.3) * min(shape))
        pool.append(ImageSpec(f"square{i}", "square", shape, radius,
                              float(rng.uniform(1.0, 3.0)), 400 + i))
    pool.append(ImageSpec("flat0", "flat", (128, 128), 0.0, 0.0, 500))
    pool.append(ImageSpec("flat1", "flat", (97, 160), 0.0, 0.0, 501))
    pool.append(ImageSpec("disc_big", "disc", (1024, 1024), 150.0, 2.0, 0))
    pool.append(ImageSpec("nav_big", "nav", (1024, 1024), 150.0, 2.0, 1))
    return {spec.key: spec for spec in pool}


IMAGES: dict[str, ImageSpec] = _image_pool()


# ---------------------------------------------------------------------------
# Star-shaped blobs and rotated squares: non-circular edges
# ---------------------------------------------------------------------------


def _blob_harmonics(spec: ImageSpec) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(spec.seed + 7)
    k = np.arange(2, 6)
    amp = rng.uniform(-0.12, 0.12, k.size) / (k - 1)
    phase = rng.uniform(0.0, 2 * np.pi, k.size)
    return amp, phase


def _centre(spec: ImageSpec) -> tuple[float, float]:
    h, w = spec.shape
    return spec.centre_frac[0] * (h - 1), spec.centre_frac[1] * (w - 1)


def _blob_rho(spec: ImageSpec, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    amp, phase = _blob_harmonics(spec)
    k = np.arange(2, 6)[:, None]
    arg = k * phi[None, :] + phase[:, None]
    rho = spec.radius * (1.0 + np.sum(amp[:, None] * np.cos(arg), axis=0))
    drho = spec.radius * np.sum(-amp[:, None] * k * np.sin(arg), axis=0)
    return rho, drho


def _square_frame(spec: ImageSpec) -> float:
    return float(np.random.default_rng(spec.seed + 11).uniform(0.0, np.pi / 2))


def make_image(spec: ImageSpec) -> np.ndarray:
    """The image of ``spec`` (deterministic)."""
    if spec.kind == "disc":
        return disc_scene(shape=spec.shape, radius=spec.radius,
                          noise_sigma=spec.noise_sigma, seed=spec.seed).image
    if spec.kind == "nav":
        return navigation_scene(shape=spec.shape, radius=spec.radius,
                                noise_sigma=spec.noise_sigma, seed=spec.seed).image
    h, w = spec.shape
    if spec.kind == "flat":
        # all zeros: no gradient anywhere, so no edge and DT = 64 everywhere. (A
        # non-zero constant is not flat: Sobel's zero padding makes the frame an edge.)
        return np.zeros((h, w))
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
    cv, cu = _centre(spec)
    dv, du = vv - cv, uu - cu
    if spec.kind == "blob":
        rho, _ = _blob_rho(spec, np.arctan2(du, dv).ravel())
        inside = np.hypot(dv, du) <= rho.reshape(h, w)
    else:  # square
        a = _square_frame(spec)
        pv = math.cos(a) * dv + math.sin(a) * du
        pu = -math.sin(a) * dv + math.cos(a) * du
        inside = np.maximum(np.abs(pv), np.abs(pu)) <= spec.radius
    rng = np.random.default_rng(spec.seed)
    return np.where(inside, 90.0, 10.0) + rng.normal(0.0, spec.noise_sigma, (h, w))


def _blob_edge(spec: ImageSpec, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    phi = np.sort(rng.uniform(0.0, 2 * np.pi, n))
    rho, drho = _blob_rho(spec, phi)
    cv, cu = _centre(spec)
    c, s = np.cos(phi), np.sin(phi)
    pts = np.stack([cv + rho * c, cu + rho * s], axis=1)
    tangent = np.stack([drho * c - rho * s, drho * s + rho * c], axis=1)
    normal = np.stack([tangent[:, 1], -tangent[:, 0]], axis=1)
    normal /= np.hypot(normal[:, 0], normal[:, 1])[:, None]
    inward = np.sign(-np.sum(normal * (pts - [cv, cu]), axis=1))
    return pts, normal * inward[:, None]


def _square_edge(spec: ImageSpec, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    a = _square_frame(spec)
    side = rng.integers(0, 4, n)
    along = rng.uniform(-0.85, 0.85, n) * spec.radius
    outward = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])[side]
    local = outward * spec.radius + outward[:, ::-1] * along[:, None]
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    cv, cu = _centre(spec)
    return local @ rot.T + [cv, cu], -(outward @ rot.T)


def _place(pts: np.ndarray, nrm: np.ndarray, offset: tuple[float, float], rotation: float
           ) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
    """Model vertices that (offset, rotation about their centroid) maps onto ``pts``."""
    mean = pts.mean(axis=0)
    pivot = mean - np.asarray(offset)
    c, s = math.cos(-rotation), math.sin(-rotation)
    rot = np.array([[c, -s], [s, c]])
    return (pts - mean) @ rot.T + pivot, nrm @ rot.T, (float(pivot[0]), float(pivot[1]))


# ---------------------------------------------------------------------------
# Case families
# ---------------------------------------------------------------------------


def _sigmas(rng: np.random.Generator, n: int) -> np.ndarray:
    choice = rng.integers(0, 3)
    if choice == 0:
        return np.ones(n)
    if choice == 1:
        return np.full(n, float(rng.uniform(0.5, 2.5)))
    return rng.uniform(0.4, 3.0, n)  # non-uniform


def _window(rng: np.random.Generator, offset: tuple[float, float]) -> tuple[int, int]:
    need = int(math.ceil(max(abs(offset[0]), abs(offset[1])))) + 2
    pick = rng.integers(0, 6)
    if pick == 0:
        return (30, 30)
    if pick == 1:  # odd, asymmetric
        return (need + int(rng.integers(0, 5)), need + int(rng.integers(3, 9)))
    m = need + int(rng.integers(0, 8))
    return (m, m)


def _polyline(spec: ImageSpec, rng: np.random.Generator, *, rotation: float = 0.0,
              outliers: float = 0.0, max_offset: float = 8.0
              ) -> tuple[np.ndarray, np.ndarray, tuple[float, float], tuple[float, float], float]:
    """Vertices, normals, truth offset, pivot and pivot distance for ``spec``."""
    offset = (float(rng.uniform(-max_offset, max_offset)), float(rng.uniform(-max_offset, max_offset)))
    n = int(rng.choice([12, 40, 100, 200, 333]))
    if spec.shape[0] >= 1024:
        n = int(rng.choice([200, 2000]))
    if spec.kind == "disc":
        sc = disc_scene(shape=spec.shape, radius=spec.radius, noise_sigma=spec.noise_sigma,
                        seed=spec.seed, n_vertices=n, offset_vu=offset, rotation_rad=rotation,
                        outlier_fraction=outliers)
        p = sc.polyline
        return p.vertices_vu, p.normals_vu, offset, sc.pivot_vu, sc.pivot_distance_px
    if spec.kind == "nav":
        sc = navigation_scene(shape=spec.shape, radius=spec.radius, noise_sigma=spec.noise_sigma,
                              seed=spec.seed, n_vertices=max(n // 3, 4), offset_vu=offset,
                              rotation_rad=rotation)
        keep = [p for p, use in zip(sc.polylines, rng.integers(0, 2, 3) | [1, 0, 0], strict=True) if use]
        verts = np.concatenate([p.vertices_vu for p in keep])
        nrms = np.concatenate([p.normals_vu for p in keep])
        return verts, nrms, offset, sc.pivot_vu, sc.pivot_distance_px
    if spec.kind == "blob":
        pts, nrm = _blob_edge(spec, n, rng)
    elif spec.kind == "square":
        pts, nrm = _square_edge(spec, n, rng)
    else:  # flat: an arbitrary circle, there is no edge to find
        phi = rng.uniform(0.0, 2 * np.pi, n)
        cv, cu = _centre(spec)
        r = 0.3 * min(spec.shape)
        pts = np.stack([cv + r * np.cos(phi), cu + r * np.sin(phi)], axis=1)
        nrm = -np.stack([np.cos(phi), np.sin(phi)], axis=1)
    if outliers > 0:
        idx = rng.choice(n, int(round(outliers * n)), replace=False)
        pts = pts.copy()
        pts[idx] -= 30.0 * nrm[idx]
    verts, nrms, pivot = _place(pts, nrm, offset, rotation)
    h, w = spec.shape
    distance = max(math.hypot(pivot[0] - (h - 1) / 2, pivot[1] - (w - 1) / 2), 1.0)
    return verts, nrms, offset, pivot, distance


def _tunables(rng: np.random.Generator) -> dict[str, Any]:
    """Occasionally non-default LM knobs."""
    kw: dict[str, Any] = {}
    if rng.random() < 0.25:
        kw["max_iterations"] = int(rng.choice([3, 8, 60]))
    if rng.random() < 0.2:
        kw["damping"] = float(rng.choice([0.0, 1e-6, 0.1, 3.0]))
    if rng.random() < 0.2:
        kw["step_tolerance_px"] = float(rng.choice([0.0, 1e-6, 0.05]))
    if rng.random() < 0.2:
        kw["tukey_c"] = float(rng.uniform(2.0, 8.0))
    return kw


_FAMILIES: list[tuple[str, int, tuple[str, ...]]] = [
    # (family, count, image kinds)
    ("translation", 80, ("disc", "blob", "nav", "square")),
    ("rotation", 40, ("nav", "blob", "square", "disc")),
    ("trust_region", 25, ("disc", "blob", "nav")),
    ("tikhonov", 25, ("disc", "blob", "nav", "square")),
    ("ridge", 25, ("disc", "blob", "nav")),
    ("no_polarity", 25, ("disc", "blob", "nav", "square")),
    ("outliers", 20, ("disc", "blob")),
    ("degenerate", 15, ("disc", "blob", "nav", "flat")),
    ("max_iterations_0", 15, ("disc", "blob", "nav")),
    ("flat_dt", 12, ("flat",)),
    ("partly_outside", 20, ("blob_edge",)),
    ("random_walk", 15, ("disc", "blob", "square")),
]


def _pick_image(rng: np.random.Generator, kind: str) -> ImageSpec:
    if kind == "blob_edge":
        keys = [k for k, s in IMAGES.items() if s.kind == "blob" and s.centre_frac != (0.5, 0.5)]
    else:
        keys = [k for k, s in IMAGES.items()
                if s.kind == kind and s.shape[0] < 1024 and s.centre_frac == (0.5, 0.5)]
    return IMAGES[keys[int(rng.integers(0, len(keys)))]]


def _make_case(family: str, index: int, rng: np.random.Generator, kinds: tuple[str, ...]) -> ParityCase:
    spec = _pick_image(rng, kinds[index % len(kinds)])
    kw: dict[str, Any] = _tunables(rng)
    rotation = 0.0
    fit_rotation = family == "rotation" or (family in ("tikhonov", "ridge", "max_iterations_0",
                                                        "flat_dt") and rng.random() < 0.35)
    if fit_rotation:
        rotation = float(rng.uniform(-0.03, 0.03))
    outliers = float(rng.choice([0.1, 0.2, 0.3])) if family == "outliers" else 0.0
    verts, nrms, offset, pivot, distance = _polyline(spec, rng, rotation=rotation, outliers=outliers)
    n = verts.shape[0]
    sigmas = _sigmas(rng, n)
    jitter = (0.0, 0.0)
    if rng.random() < 0.3:
        jitter = (float(rng.uniform(-0.5, 0.5)), float(rng.uniform(-0.5, 0.5)))
    window = _window(rng, offset)
    if fit_rotation:
        kw.update(fit_rotation=True, pivot_distance_px=distance)
        if rng.random() < 0.5:
            kw["pivot_vu"] = pivot
    elif rng.random() < 0.1:  # a fixed, non-zero rotation that is not fitted
        kw["initial_rotation_rad"] = float(rng.uniform(-0.02, 0.02))
    if family == "trust_region":
        kw["trust_region_px"] = float(rng.choice([0.0, 0.25, 0.5, 1.0, 1.0, 2.0]))
    elif family == "tikhonov":
        kw["tikhonov_alpha"] = float(rng.choice([1e-3, 0.01, 0.1, 1.0, 10.0]))
    elif family == "ridge":
        kw["final_gradient_ridge"] = True
    elif family == "no_polarity":
        kw["use_polarity"] = False
        if rng.random() < 0.5:  # flipped normals do not matter without polarity
            flip = rng.random(n) < 0.3
            nrms = np.where(flip[:, None], -nrms, nrms)
    elif family == "degenerate":
        mode = index % 3
        if mode == 0 or spec.kind == "flat":  # every normal against the gradient
            nrms = -nrms
        elif mode == 1:  # tiny sigmas far from any edge: Tukey rejects all
            verts = verts + 9.0
            sigmas = np.full(n, 0.05)
            window = (1, 1)
        else:  # entirely outside the image
            verts = verts + [3.0 * spec.shape[0], -2.0 * spec.shape[1]]
    elif family == "max_iterations_0":
        kw["max_iterations"] = 0
        if rng.random() < 0.4:
            kw["final_gradient_ridge"] = True
    elif family == "flat_dt":
        # DT = 64 everywhere: Tukey keeps the vertices only if sigma >= 64/c.
        sigmas = np.full(n, float(rng.choice([20.0, 40.0, 5.0])))
        kw["use_polarity"] = bool(rng.random() < 0.2)  # zero gradient: all rejected
        window = (int(rng.integers(0, 6)), int(rng.integers(0, 6)))
    elif family == "partly_outside":
        kw["use_polarity"] = bool(rng.random() < 0.6)
    elif family == "random_walk":
        start = np.array(spec.shape) * rng.uniform(0.2, 0.8, 2)
        steps = rng.normal(0.0, 2.5, (n, 2))
        verts = start + np.cumsum(steps, axis=0)
        ang = rng.uniform(0.0, 2 * np.pi, n)
        nrms = np.stack([np.cos(ang), np.sin(ang)], axis=1)
        sigmas = rng.uniform(0.5, 4.0, n)
        kw["use_polarity"] = False
        window = (int(rng.integers(2, 12)), int(rng.integers(2, 12)))
    return ParityCase(
        case_id=f"{family}-{index:02d}-{spec.key}",
        family=family,
        image=spec,
        vertices=np.ascontiguousarray(verts, dtype=np.float64),
        normals=np.ascontiguousarray(nrms, dtype=np.float64),
        sigmas=np.ascontiguousarray(sigmas, dtype=np.float64),
        window=window,
        jitter=jitter,
        lm_kwargs=kw,
    )


def _large_cases() -> list[ParityCase]:
    """The scenes of :ref:`contract-scenes` on 1024 x 1024: base, +-50 window, rotation, outliers, ridge."""
    disc, nav = IMAGES["disc_big"], IMAGES["nav_big"]
    out: list[ParityCase] = []

    def add(name: str, spec: ImageSpec, sc: Any, window: int, polylines: int = 1, **kw: Any) -> None:
        polys = sc.polylines[:polylines]
        out.append(ParityCase(
            case_id=f"large-{name}", family="large", image=spec,
            vertices=np.concatenate([p.vertices_vu for p in polys]),
            normals=np.concatenate([p.normals_vu for p in polys]),
            sigmas=np.concatenate([p.sigmas for p in polys]),
            window=(window, window), lm_kwargs=kw))

    base = dict(shape=disc.shape, radius=disc.radius, noise_sigma=disc.noise_sigma, seed=disc.seed)
    add("disc", disc, disc_scene(**base), 30)
    add("disc-n2000-w50", disc, disc_scene(**base, n_vertices=2000), 50, trust_region_px=1.0)
    add("disc-outliers", disc, disc_scene(**base, outlier_fraction=0.1), 30)
    nb = dict(shape=nav.shape, radius=nav.radius, noise_sigma=nav.noise_sigma, seed=nav.seed)
    sc = navigation_scene(**nb, rotation_rad=0.01)
    add("nav-rotation", nav, sc, 30, polylines=3, fit_rotation=True,
        pivot_vu=sc.pivot_vu, pivot_distance_px=sc.pivot_distance_px)
    add("nav-ridge", nav, navigation_scene(**nb), 30, polylines=2, final_gradient_ridge=True)
    return out


def build_cases() -> list[ParityCase]:
    """Every parity case, in a fixed order (322 small + 5 large)."""
    cases: list[ParityCase] = []
    for f_index, (family, count, kinds) in enumerate(_FAMILIES):
        for i in range(count):
            rng = np.random.default_rng([7, f_index, i])
            cases.append(_make_case(family, i, rng, kinds))
    return cases + _large_cases()


# ---------------------------------------------------------------------------
# The contract's state of a pose, and the conditioning of a fit
# ---------------------------------------------------------------------------

#: The paths' rounding differs by up to ~1e-13 px per step (measured on the
#: converging fits of the parity sweep under three OpenBLAS kernels); a fit
#: that amplifies a perturbation of its start at most 1e3-fold keeps that
#: 1e-13 px below the 1e-9 px parity bar with a 10x margin.
AMPLIFICATION_MAX = 1e3
#: A solve loses ~kappa * 1e-16 of relative accuracy to rounding of ``H``;
#: for steps of a few px to stay within 1e-9 px that is kappa <= ~1e6. Above
#: it the system is near singular, and whether LU meets an exactly zero pivot
#: (:ref:`contract-lm` step 2d: solve, or pinvh) depends on how ``H`` was rounded.
KAPPA_MAX = 1e6


def spec_state(dt: np.ndarray, vertices: np.ndarray, sigmas: np.ndarray, pol: np.ndarray,
               pose: tuple[float, float, float], pivot: tuple[float, float], fit_rotation: bool,
               c: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residuals, weights and Jacobian at ``pose`` (NumPy; :ref:`contract-numerics`, :ref:`contract-lm`)."""

    def place(theta: float) -> np.ndarray:
        if theta == 0.0:
            v, u = vertices[:, 0], vertices[:, 1]
        else:
            co, si = math.cos(theta), math.sin(theta)
            v = pivot[0] + co * (vertices[:, 0] - pivot[0]) - si * (vertices[:, 1] - pivot[1])
            u = pivot[1] + si * (vertices[:, 0] - pivot[0]) + co * (vertices[:, 1] - pivot[1])
        return np.stack([v + pose[0], u + pose[1]], axis=1)

    pos = place(pose[2])
    s = ref.sample_dt_bilinear
    cols = [(s(dt, pos + [0.25, 0.0]) - s(dt, pos - [0.25, 0.0])) / 0.5,
            (s(dt, pos + [0.0, 0.25]) - s(dt, pos - [0.0, 0.25])) / 0.5]
    if fit_rotation:
        cols.append((s(dt, place(pose[2] + 1e-3)) - s(dt, place(pose[2] - 1e-3))) / 2e-3)
    r = np.where(pol, s(dt, pos), 1.0e6)
    w = (1.0 / sigmas**2) * ref.tukey_biweight_weights(r / sigmas, c=c) * pol
    return r, w, np.stack(cols, axis=1)


def scaled_condition(jac: np.ndarray, w: np.ndarray) -> float:
    """Condition number of ``D^-1/2 (J^T W J) D^-1/2``, ``D = diag(J^T W J)``.

    The LM damps with ``lambda diag(H)``: scaled, the damped matrix is
    ``S + lambda I`` with eigenvalues ``s_k + lambda``, so its condition
    number is largest, ``kappa(S)``, at ``lambda = 0``. 1 where no vertex
    has weight (no system is solved), inf where a parameter has no information.
    """
    if not (w > 0).any():
        return 1.0
    a = np.sqrt(w)[:, None] * jac
    info = a.T @ a
    d = np.sqrt(np.diag(info))
    if not (d > 0).all():
        return math.inf
    ev = np.linalg.eigvalsh(info / d[:, None] / d[None, :])
    return float(ev[-1] / ev[0]) if ev[0] > 0 else math.inf
