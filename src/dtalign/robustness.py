"""A scored benchmark of robustness: seeded hard scenes and a harness.

The parity scenes of :mod:`dtalign.scenes` are easy on purpose: one clean
edge and nothing to confuse it with. A navigation frame is not: a
neighbouring ring edge, a crater rim inside a limb or a terminator next to
it offer the fit a second basin, and the local LM converges into whichever
basin the coarse seed picks, reporting a small rms and a tight covariance
either way. This module builds scenes that are hard in those ways and
scores any fit function on them, so "no confident wrong answer" is a
number, not a hope.

* Each *family* is a function ``(seed) -> HardScene``; :data:`FAMILIES`
  maps the family names to them, in table order. Scenes are small (256 x
  256) and deterministic in ``seed``, and each knows its truth.
* :func:`evaluate` runs a fit function on a set of families and seeds and
  returns one :class:`Row` per family: fraction correct, fraction
  confidently wrong, fraction flagged, median time per fit.
* :func:`format_table` renders the rows as a markdown table;
  ``python -m dtalign.robustness`` prints it for :func:`plain_fit`.

Importing this module imports NumPy only; :func:`plain_fit` imports the
pipeline (and through it the compiled kernels) when first called.

Conventions are those of :mod:`dtalign.scenes`: coordinates ``(v, u)``,
normals point to the bright side of each edge, and the model polyline sits
at ``true edge - true_offset_vu``, so a correct fit returns the offset.
Edges are anti-aliased (each pixel's value is the fraction of it on the
bright side, to first order in the signed distance), so the true edge is
where the model says it is to well under a pixel.
"""

from __future__ import annotations

import argparse
import logging
import math
import statistics
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .scenes import Polyline

__all__ = [
    "CORRECT_TOLERANCE_PX",
    "FAMILIES",
    "HardScene",
    "Row",
    "Trial",
    "crater_rim",
    "evaluate",
    "format_table",
    "heavy_noise",
    "main",
    "outliers",
    "parallel_rings",
    "plain_fit",
    "small_window",
    "terminator_limb",
]

FloatArray = NDArray[np.float64]

#: A fit is correct when it is within this distance of the truth across the
#: edge (or in 2-D for a curved edge): the issue's criterion, and about
#: three times the one-sigma of a clean limb fit on these scenes.
CORRECT_TOLERANCE_PX: float = 0.5

#: Every scene's image shape: a fit on it takes milliseconds, so a suite of
#: six families x 20 seeds runs in seconds once the kernels are compiled.
_SHAPE: tuple[int, int] = (256, 256)

#: The noise of every family but ``heavy_noise``, in DN on a 100 DN body:
#: the level of the scenes of :ref:`contract-scenes`.
_NOISE_DN: float = 2.0

#: Vertices per model polyline: dense enough that the robust cost is smooth,
#: few enough that the LM costs microseconds.
_N_VERTICES: int = 120

#: Stride added to the seed for each independent random stream, so the
#: noise of seed ``s`` is never the geometry of seed ``s + 1``.
_NOISE_STREAM: int = 1_000_003


# ---------------------------------------------------------------------------
# Scenes
# ---------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class HardScene:
    """A hard synthetic scene and its truth.

    Attributes
    ----------
    family : str
        The family name (a key of :data:`FAMILIES`).
    seed : int
        The seed the scene was built from.
    image : ndarray, shape (H, W)
        The noisy image in DN.
    clean_image : ndarray, shape (H, W)
        The same image before the noise was added.
    noise_sigma : float
        The standard deviation of the added Gaussian noise.
    polyline : Polyline
        The model polyline, at ``true edge - true_offset_vu``; normals point
        to the bright side.
    search_window_vu : tuple of int
        The coarse-search margin a caller would use.
    use_polarity : bool
        True for a limb or terminator model, False for a ring edge (today's
        ring technique fits without polarity).
    true_offset_vu : tuple of float
        The offset a correct fit returns.
    true_rotation_rad : float
        Always 0.0: the suite tests acquisition, not rotation.
    across_vu : tuple of float or None
        The unit direction ``(v, u)`` along which "correct" is measured (the
        normal of a straight edge, whose along-edge offset is unobservable),
        or None to use the full 2-D error.
    reachable : bool
        Whether a correct answer lies inside the search window. When False
        no answer counts as correct: the only right outcome is a flag.
    decoy_offset_vu : tuple of float or None
        The offset a fit locked on the wrong feature returns: the shift that
        lands the model on the decoy edge, or for ``small_window`` the truth
        clamped to the window. None when the scene has no single decoy.
    decoy_vertices_vu : ndarray, shape (M, 2)
        Points on the decoy edge (empty when there is none), one per model
        vertex and in the same order: where the image must have an edge for
        the scene to be as hard as it claims.
    true_edge_mask : ndarray of bool, shape (N,)
        The model vertices that lie on the true edge once moved by the
        truth (all but the displaced ones of ``outliers``).
    description : str
        One line saying what makes the scene hard.
    """

    family: str
    seed: int
    image: FloatArray
    clean_image: FloatArray
    noise_sigma: float
    polyline: Polyline
    search_window_vu: tuple[int, int]
    use_polarity: bool
    true_offset_vu: tuple[float, float]
    across_vu: tuple[float, float] | None
    reachable: bool
    true_rotation_rad: float = 0.0
    decoy_offset_vu: tuple[float, float] | None = None
    decoy_vertices_vu: FloatArray = field(default_factory=lambda: np.zeros((0, 2)), repr=False)
    true_edge_mask: NDArray[np.bool_] = field(
        default_factory=lambda: np.zeros(0, dtype=bool), repr=False
    )
    description: str = ""

    def __post_init__(self) -> None:
        if self.true_edge_mask.shape[0] == 0:
            object.__setattr__(self, "true_edge_mask", np.ones(len(self.polyline), dtype=bool))

    @property
    def true_vertices_vu(self) -> FloatArray:
        """The model vertices moved by the truth (on the true edge, outliers aside)."""
        return self.polyline.vertices_vu + np.asarray(self.true_offset_vu)

    def error_px(self, offset_vu: Any) -> float:
        """Distance of a fitted offset from the truth, across the edge or in 2-D."""
        d = np.asarray(offset_vu, dtype=np.float64) - np.asarray(self.true_offset_vu)
        if self.across_vu is not None:
            return float(abs(d @ np.asarray(self.across_vu)))
        return float(math.hypot(d[0], d[1]))


def _grid() -> tuple[FloatArray, FloatArray]:
    vv, uu = np.mgrid[0 : _SHAPE[0], 0 : _SHAPE[1]]
    return vv.astype(np.float64), uu.astype(np.float64)


def _coverage(signed_distance: FloatArray) -> FloatArray:
    """Fraction of a pixel on the bright side of an edge at this signed distance.

    The box-filter model: exact for an axis-aligned straight edge and within
    a few hundredths of a pixel for a tilted or gently curved one.
    """
    return np.clip(signed_distance + 0.5, 0.0, 1.0)


def _noisy(clean: FloatArray, noise_sigma: float, seed: int) -> FloatArray:
    rng = np.random.default_rng(seed + _NOISE_STREAM)
    return clean + rng.normal(0.0, noise_sigma, clean.shape)


def _random_offset(rng: np.random.Generator, low: float, high: float) -> FloatArray:
    """An offset of uniform length in ``[low, high]`` and uniform direction."""
    r = rng.uniform(low, high)
    a = rng.uniform(0.0, 2.0 * math.pi)
    return np.array([r * math.cos(a), r * math.sin(a)])


def _pair(x: Any) -> tuple[float, float]:
    return float(x[0]), float(x[1])


def _polyline(name: str, true_vu: FloatArray, normals: FloatArray, offset: FloatArray) -> Polyline:
    n = normals / np.hypot(normals[:, 0], normals[:, 1])[:, None]
    return Polyline(name, true_vu - offset, n, np.ones(true_vu.shape[0]))


def _scene(family: str, seed: int, image: FloatArray, clean: FloatArray, noise: float,
           polyline: Polyline, window: int, offset: FloatArray, **rest: Any) -> HardScene:
    """A family's scene with a symmetric search window; polarity used, the error in
    2-D and the truth reachable unless ``rest`` says otherwise."""
    rest = {"use_polarity": True, "across_vu": None, "reachable": True} | rest
    return HardScene(family=family, seed=seed, image=image, clean_image=clean,
                     noise_sigma=noise, polyline=polyline, search_window_vu=(window, window),
                     true_offset_vu=_pair(offset), **rest)


def parallel_rings(seed: int) -> HardScene:
    """Two parallel straight ring edges of the same polarity, 5-20 px apart.

    The image is a staircase across a tilted line (0, 50 and 100 DN): both
    edges are bright on the same side, so neither polarity nor shape tells
    them apart. The model is one of them (chosen by the seed); the other is
    the decoy. Fitted without polarity, as today's ring technique does; the
    along-edge offset is unobservable, so "correct" is measured across.
    """
    rng = np.random.default_rng(seed)
    theta = rng.uniform(-math.radians(25.0), math.radians(25.0))
    normal = np.array([math.cos(theta), math.sin(theta)])
    tangent = np.array([-normal[1], normal[0]])
    spacing = rng.uniform(5.0, 20.0)
    model_is_lower = bool(rng.integers(0, 2))
    e_model = rng.uniform(-10.0, 10.0)
    e_decoy = e_model + (spacing if model_is_lower else -spacing)
    across = rng.choice([-1.0, 1.0]) * rng.uniform(2.0, 10.0)
    along = rng.uniform(-5.0, 5.0)
    offset = across * normal + along * tangent

    vv, uu = _grid()
    centre = np.array([(_SHAPE[0] - 1) / 2.0, (_SHAPE[1] - 1) / 2.0])
    s = normal[0] * (vv - centre[0]) + normal[1] * (uu - centre[1])
    clean = 50.0 * _coverage(s - min(e_model, e_decoy)) + 50.0 * _coverage(s - max(e_model, e_decoy))
    image = _noisy(clean, _NOISE_DN, seed)

    tau = np.linspace(-0.35 * _SHAPE[1], 0.35 * _SHAPE[1], _N_VERTICES)
    true_vu = centre + e_model * normal + tau[:, None] * tangent
    normals = np.tile(normal, (_N_VERTICES, 1))
    decoy_shift = (e_decoy - e_model) * normal
    return _scene(
        "parallel_rings", seed, image, clean, _NOISE_DN,
        _polyline("ring", true_vu, normals, offset), 30, offset,
        use_polarity=False,
        across_vu=_pair(normal),
        decoy_offset_vu=_pair(offset + decoy_shift),
        decoy_vertices_vu=true_vu + decoy_shift,
        description=f"ring edges {spacing:.1f} px apart, same polarity",
    )


def crater_rim(seed: int) -> HardScene:
    """A limb arc with a large dark crater just inside it: a rim of reversed polarity.

    A bright disc (100 DN) holds a crater (radius 0.85-0.97 of the disc's,
    floor 35 DN) whose rim nearest the limb runs 3-8 px inside it, nearly
    parallel to it, and is bright on its outer side: the opposite of the
    limb. The model is the visible limb arc, 60 degrees centred on the
    crater; the decoy is the crater's near rim.
    """
    rng = np.random.default_rng(seed)
    radius = rng.uniform(80.0, 95.0)
    phi0 = rng.uniform(0.0, 2.0 * math.pi)
    r0 = np.array([math.cos(phi0), math.sin(phi0)])
    crater_radius = rng.uniform(0.85, 0.97) * radius
    gap = rng.uniform(3.0, 8.0)
    offset = _random_offset(rng, 2.0, 8.0)

    vv, uu = _grid()
    centre = np.array([(_SHAPE[0] - 1) / 2.0, (_SHAPE[1] - 1) / 2.0])
    crater_centre = centre + (radius - gap - crater_radius) * r0
    disc = _coverage(radius - np.hypot(vv - centre[0], uu - centre[1]))
    crater = _coverage(crater_radius - np.hypot(vv - crater_centre[0], uu - crater_centre[1]))
    clean = 100.0 * disc * (1.0 - 0.65 * crater)
    image = _noisy(clean, _NOISE_DN, seed)

    phi = phi0 + np.linspace(-math.radians(30.0), math.radians(30.0), _N_VERTICES)
    radial = np.stack([np.cos(phi), np.sin(phi)], axis=1)
    true_vu = centre + radius * radial
    rim = crater_centre + crater_radius * radial
    return _scene(
        "crater_rim", seed, image, clean, _NOISE_DN,
        _polyline("limb", true_vu, -radial, offset), 20, offset,
        decoy_offset_vu=_pair(offset - gap * r0),
        decoy_vertices_vu=rim,
        description=f"crater rim {gap:.1f} px inside the limb, reversed polarity",
    )


def terminator_limb(seed: int, *, rotation_rad: float = 0.0,
                    centre_shift_vu: tuple[float, float] = (0.0, 0.0)) -> HardScene:
    """A thin crescent: the terminator runs 3-8 px inside the limb.

    A body lit from +u, of which only a crescent is lit: between the right
    half of its circle (the limb, bright inside) and the right half of an
    ellipse (the terminator, bright outside), so the two edges have
    opposite polarity and nearly the same shape. Even seeds model the
    terminator, odd seeds the limb, over the 72 degrees about the equator
    (clear of the cusps, where the two edges meet); the other edge is the
    decoy.

    Parameters
    ----------
    seed : int
        The scene's seed.
    rotation_rad : float, optional
        Turns the whole scene (light, crescent and polyline) by this angle
        about the image's centre, from +u toward +v (the body's centre, 20
        px from the image's away from the light, turns with it).
    centre_shift_vu : tuple of float, optional
        Moves the body's centre by this much, px. With the defaults the
        crescent is mirror-symmetric about a line between pixel rows, so
        the pixel quantisation of its edges cancels between its halves:
        the docs' uncertainty page measures what a turned, shifted
        crescent changes.
    """
    rng = np.random.default_rng(seed)
    radius = rng.uniform(85.0, 100.0)
    width = rng.uniform(3.0, 8.0)
    b = radius - width
    offset = _random_offset(rng, 2.0, 8.0)
    model_terminator = seed % 2 == 0

    # the crescent's own frame: e_u toward the light, e_v across it
    s, c = math.sin(rotation_rad), math.cos(rotation_rad)
    e_v, e_u = np.array([c, -s]), np.array([s, c])
    centre = (np.array([(_SHAPE[0] - 1) / 2.0, (_SHAPE[1] - 1) / 2.0])
              + np.asarray(centre_shift_vu, dtype=np.float64) - 20.0 * e_u)
    vv, uu = _grid()
    dv = (vv - centre[0]) * c - (uu - centre[1]) * s
    du = (vv - centre[0]) * s + (uu - centre[1]) * c
    disc = _coverage(radius - np.hypot(dv, du))
    # First-order signed distance outside the ellipse: f / |grad f|.
    f = (dv / radius) ** 2 + (du / b) ** 2 - 1.0
    grad = 2.0 * np.hypot(dv / radius**2, du / b**2)
    outside = _coverage(f / np.maximum(grad, 1e-12))
    clean = 100.0 * disc * outside * (du >= 0.0)
    image = _noisy(clean, _NOISE_DN, seed)

    def frame(a: FloatArray, b_: FloatArray) -> FloatArray:  # (v, u) of frame vectors
        return a[:, None] * e_v + b_[:, None] * e_u

    ang = np.linspace(-0.2 * math.pi, 0.2 * math.pi, _N_VERTICES)
    sin, cos = np.sin(ang), np.cos(ang)
    limb = centre + frame(radius * sin, radius * cos)
    limb_n = frame(-sin, -cos)
    term = centre + frame(radius * sin, b * cos)
    term_n = frame(sin / radius, cos / b)
    if model_terminator:
        name, true_vu, normals, decoy = "terminator", term, term_n, limb
        decoy_shift = width * e_u
    else:
        name, true_vu, normals, decoy = "limb", limb, limb_n, term
        decoy_shift = -width * e_u
    return _scene(
        "terminator_limb", seed, image, clean, _NOISE_DN,
        _polyline(name, true_vu, normals, offset), 20, offset,
        decoy_offset_vu=_pair(offset + decoy_shift),
        decoy_vertices_vu=decoy,
        description=f"{name} model, crescent {width:.1f} px wide",
    )


def _limb_scene(
    rng: np.random.Generator, noise_sigma: float, seed: int
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """A bright disc and its full limb: noisy and clean images, the true limb, its normals."""
    radius = rng.uniform(60.0, 90.0)
    vv, uu = _grid()
    centre = np.array([(_SHAPE[0] - 1) / 2.0, (_SHAPE[1] - 1) / 2.0])
    clean = 100.0 * _coverage(radius - np.hypot(vv - centre[0], uu - centre[1]))
    image = _noisy(clean, noise_sigma, seed)
    phi = 2.0 * math.pi * np.arange(_N_VERTICES) / _N_VERTICES
    radial = np.stack([np.cos(phi), np.sin(phi)], axis=1)
    return image, clean, centre + radius * radial, -radial


def small_window(seed: int) -> HardScene:
    """A clean limb whose true offset (12-20 px) lies outside a 3-5 px window.

    The largest offset component exceeds the window margin by at least
    3.4 px, so no shift the search may return is correct: the only right
    outcome is a flagged result (the seed on the window's edge says so).
    """
    rng = np.random.default_rng(seed)
    margin = int(rng.integers(3, 6))
    offset = _random_offset(rng, 12.0, 20.0)
    image, clean, true_vu, normals = _limb_scene(rng, _NOISE_DN, seed)
    return _scene(
        "small_window", seed, image, clean, _NOISE_DN,
        _polyline("limb", true_vu, normals, offset), margin, offset,
        reachable=False,
        decoy_offset_vu=_pair(np.clip(offset, -margin, margin)),
        description=f"offset {math.hypot(*offset):.1f} px, window +-{margin} px",
    )


def heavy_noise(seed: int) -> HardScene:
    """A limb at a contrast of 0.7-1.5 noise sigmas: its edge pixels are unreliable.

    The edge threshold scales with the noise, so few pure-noise pixels pass
    it; what fails is the limb itself, whose edge pixels are sparse and
    scattered by up to a few pixels.
    """
    rng = np.random.default_rng(seed)
    noise = 100.0 / rng.uniform(0.7, 1.5)
    offset = _random_offset(rng, 2.0, 8.0)
    image, clean, true_vu, normals = _limb_scene(rng, noise, seed)
    return _scene(
        "heavy_noise", seed, image, clean, noise,
        _polyline("limb", true_vu, normals, offset), 16, offset,
        description=f"contrast {100.0 / noise:.2f} noise sigmas",
    )


def outliers(seed: int) -> HardScene:
    """A clean limb whose model has 30 % of its vertices displaced.

    The displaced vertices (chosen by the seed) move 2-12 px along their
    normals, either way: the far ones are what the Tukey biweight drops, the
    near ones (under its 4.7 px cutoff) pull the fit.
    """
    rng = np.random.default_rng(seed)
    offset = _random_offset(rng, 2.0, 8.0)
    image, clean, true_vu, normals = _limb_scene(rng, _NOISE_DN, seed)
    poly = _polyline("limb", true_vu, normals, offset)
    count = int(round(0.3 * _N_VERTICES))
    idx = np.sort(rng.choice(_N_VERTICES, size=count, replace=False))
    shift = rng.choice([-1.0, 1.0], size=count) * rng.uniform(2.0, 12.0, size=count)
    vertices = poly.vertices_vu.copy()
    vertices[idx] += shift[:, None] * poly.normals_vu[idx]
    on_edge = np.ones(_N_VERTICES, dtype=bool)
    on_edge[idx] = False
    return _scene(
        "outliers", seed, image, clean, _NOISE_DN,
        Polyline("limb", vertices, poly.normals_vu, poly.sigmas), 16, offset,
        true_edge_mask=on_edge,
        description=f"{count} of {_N_VERTICES} vertices displaced 2-12 px",
    )


#: The families, in table order.
FAMILIES: dict[str, Callable[[int], HardScene]] = {
    "parallel_rings": parallel_rings,
    "crater_rim": crater_rim,
    "terminator_limb": terminator_limb,
    "small_window": small_window,
    "heavy_noise": heavy_noise,
    "outliers": outliers,
}


# ---------------------------------------------------------------------------
# Harness
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Trial:
    """One fit on one scene.

    Attributes
    ----------
    family : str
    seed : int
    error_px : float
        :meth:`HardScene.error_px` of the fitted offset (``nan`` when the
        offset is not finite).
    status : str
        The result's ``status`` (``'ok'`` when it has none).
    correct : bool
        Reachable and ``error_px <= CORRECT_TOLERANCE_PX``.
    time_s : float
        Wall time of the fit call.
    """

    family: str
    seed: int
    error_px: float
    status: str
    correct: bool
    time_s: float

    @property
    def flagged(self) -> bool:
        """Whether the fit said it should not be trusted (status other than ``'ok'``)."""
        return self.status != "ok"

    @property
    def confidently_wrong(self) -> bool:
        """Wrong and not flagged: the failure the suite counts."""
        return not self.correct and not self.flagged


@dataclass(frozen=True)
class Row:
    """The scores of one family.

    Attributes
    ----------
    family : str
    reachable : bool
        Whether a correct answer is reachable in this family's scenes.
    trials : tuple of Trial
        One per seed, in seed order.
    """

    family: str
    reachable: bool
    trials: tuple[Trial, ...]

    @property
    def n(self) -> int:
        """Number of scenes."""
        return len(self.trials)

    def _fraction(self, hits: Iterable[bool]) -> float:
        return sum(hits) / self.n if self.n else math.nan

    @property
    def correct(self) -> float:
        """Fraction of fits within the tolerance of the truth (status regardless)."""
        return self._fraction(t.correct for t in self.trials)

    @property
    def confidently_wrong(self) -> float:
        """Fraction of fits wrong with status ``'ok'``."""
        return self._fraction(t.confidently_wrong for t in self.trials)

    @property
    def flagged(self) -> float:
        """Fraction of fits with a status other than ``'ok'``."""
        return self._fraction(t.flagged for t in self.trials)

    @property
    def median_time_s(self) -> float:
        """Median wall time per fit, seconds."""
        return statistics.median(t.time_s for t in self.trials) if self.trials else math.nan


def _status(result: Any) -> str:
    # An enum status (such as dtalign.pipeline.status.FitStatus) is read by its value,
    # so the comparison with 'ok' does not depend on how the enum prints.
    status = getattr(result, "status", "ok")
    return str(getattr(status, "value", status))


def evaluate(
    fit_fn: Callable[[HardScene], Any],
    families: Iterable[str] | None = None,
    seeds: Iterable[int] = range(20),
    *,
    warmup: bool = True,
) -> list[Row]:
    """Score a fit function on the suite.

    Parameters
    ----------
    fit_fn : callable
        ``fit_fn(scene) -> result``, where ``result.offset_vu`` is the
        fitted ``(dv, du)`` and ``result.status`` a string: ``'ok'`` means
        confident, anything else (``'ambiguous'``, ``'failed'``, ...) counts
        as flagged. A result without ``status`` counts as ``'ok'``.
    families : iterable of str, optional
        Family names (keys of :data:`FAMILIES`); all of them when None.
    seeds : iterable of int
        The seeds of each family's scenes.
    warmup : bool
        Call ``fit_fn`` once on the first scene before timing, so the
        first timed fit does not pay for compiling or loading kernels.

    Returns
    -------
    list of Row
        One per family, in the order given. A fit is correct when the scene
        is reachable and the fitted offset is within
        :data:`CORRECT_TOLERANCE_PX` of the truth along ``across_vu`` (or
        in 2-D); confidently wrong when not correct and its status is
        ``'ok'``. Only the ``fit_fn`` call is timed.

    Raises
    ------
    ValueError
        If a family name is unknown.

    Notes
    -----
    An exception raised by ``fit_fn`` propagates: a fit that refuses a
    scene is a bug to see, not a score.
    """
    names = list(FAMILIES) if families is None else list(families)
    for name in names:
        if name not in FAMILIES:
            raise ValueError(f"families: unknown family {name!r}; expected one of {list(FAMILIES)}")
    seed_list = [int(s) for s in seeds]
    rows: list[Row] = []
    warm = not warmup
    for name in names:
        trials = []
        reachable = True
        for seed in seed_list:
            scene = FAMILIES[name](seed)
            reachable = scene.reachable
            if not warm:
                fit_fn(scene)
                warm = True
            t0 = time.perf_counter()
            result = fit_fn(scene)
            elapsed = time.perf_counter() - t0
            offset = np.asarray(result.offset_vu, dtype=np.float64)
            error = scene.error_px(offset) if np.isfinite(offset).all() else math.nan
            correct = scene.reachable and error <= CORRECT_TOLERANCE_PX
            trials.append(Trial(name, seed, error, _status(result), bool(correct), elapsed))
        rows.append(Row(name, reachable, tuple(trials)))
    return rows


def format_table(rows: Sequence[Row]) -> str:
    """The rows as a markdown table, one line per family.

    Columns: family, scenes, whether a correct answer is reachable, the
    fractions correct, confidently wrong and flagged, and the median time
    per fit in milliseconds.
    """
    lines = [
        "| family | scenes | reachable | correct | confidently wrong | flagged | median ms/fit |",
        "|---|---:|:---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r.family} | {r.n} | {'yes' if r.reachable else 'no'} | {r.correct:.2f} "
            f"| {r.confidently_wrong:.2f} | {r.flagged:.2f} | {1e3 * r.median_time_s:.2f} |"
        )
    return "\n".join(lines)


def plain_fit(scene: HardScene) -> Any:
    """The plain one-call pipeline on a scene: :func:`dtalign.pipeline.fit_polyline`.

    With the scene's window, noise sigma and polarity setting, every other
    option at its default. The result's ``status`` (``ok``, ``ambiguous`` or
    ``failed``, from :mod:`dtalign.pipeline.status`) is what :func:`evaluate` reads.
    """
    from .pipeline.fit import fit_polyline

    p = scene.polyline
    return fit_polyline(
        scene.image,
        p.vertices_vu,
        p.normals_vu,
        p.sigmas,
        search_window_vu=scene.search_window_vu,
        noise_sigma=scene.noise_sigma,
        use_polarity=scene.use_polarity,
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Print the robustness table of :func:`plain_fit` (``python -m dtalign.robustness``).

    The ``dtalign`` logger's per-fit warnings are silenced during the run
    (the table counts what they say).
    """
    parser = argparse.ArgumentParser(
        prog="python -m dtalign.robustness",
        description="Score the plain pipeline on the seeded hard scenes.",
    )
    parser.add_argument("--seeds", type=int, default=20, help="scenes per family (seeds 0..N-1)")
    parser.add_argument(
        "--families", nargs="+", choices=list(FAMILIES), default=None, help="families to run"
    )
    args = parser.parse_args(argv)
    # The pipeline logs a warning per failed or suspect fit; the table counts
    # them, so a hundred lines of them would only bury it.
    log = logging.getLogger("dtalign")
    level = log.level
    log.setLevel(logging.ERROR)
    try:
        rows = evaluate(plain_fit, families=args.families, seeds=range(args.seeds))
    finally:
        log.setLevel(level)
    print(format_table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
