"""Refine a DT-LM pose against the image intensity with an :class:`~dtalign.api.profiles.EdgeProfile`.

The edge DT localises each edge at its steepest gradient, which for a
one-sided photometric edge (a limb) lies inside the geometric edge; the
integer DT adds a one-pixel ripple. After the DT-LM lock this module fits
the image's own pixels in a strip along each vertex's normal with the
profile's model (the kernels of ``dtalign._kernels.profile``, specified
by :mod:`dtalign.reference.profile`): free offset, gain, background and
the PSF (a Gaussian core, its sigma when the profile does not give it,
and wings: a fraction of the light in a wider Gaussian, :data:`FIT_WINGS`),
with the amplitude of the profile's shape basis (a reflectance law's limb
darkening) and a background slope (scattered light); Gauss-Newton with
Tukey weights. The rotation, when fitted by the DT-LM, is held at its
value: the refinement fits the offset only. A terminator (a kink, not a
step) starts from a scan, is fitted without the background slope, with
its strips recentred on it, and with an estimated sigma fitted last on
every vertex (:ref:`profiles-terminator`).

The result, :class:`ProfileRefinement`, says whether the refinement was
accepted: it is discarded when it did not converge, walked farther than
:data:`MAX_WALK_PX` from the DT lock, or fitted a non-positive gain; and
it says when the profile has no usable edge (``soft_edge``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import Any, ClassVar, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..api import checks as check
from ..api import loop
from ..api.profiles import EDGE_KINDS, EdgeProfile
from .records import from_json, to_json

__all__ = [
    "HALF_WIDTH_PX",
    "MAX_TAU_PX",
    "MIN_VERTICES",
    "edge_kind_of",
    "Misfit",
    "misfit",
    "misfitted",
    "profile_samples",
    "MAX_WALK_PX",
    "SCAN_DARK_PX",
    "SCAN_LIT_PX",
    "SCAN_STEP_PX",
    "TERMINATOR_RECENTRES",
    "TERMINATOR_CENTRED_PX",
    "TERMINATOR_FREE_SIGMA",
    "RIVAL_AGREEMENT_SIGMAS",
    "SOFT_EDGE_STEP_JUMP",
    "FIT_WINGS",
    "FLAT_CONTRAST",
    "MISFIT_BIN_PX",
    "MISFIT_LIMIT",
    "MISFIT_NOISE_SIGMAS",
    "SCATTER_LIMIT_PX",
    "SCATTER_RATIO",
    "GAIN_SCATTER_LIMIT",
    "HORN_FRACTION",
    "HORN_SHIFT_SIGMAS",
    "HORN_SHIFT_MIN_PX",
    "horns_disagree",
    "NIGHT_BOX_PX",
    "NIGHT_BLOCK_PX",
    "NIGHT_SKY_QUANTILE",
    "NIGHT_SIGMAS",
    "NIGHT_MIN_FRACTION",
    "MIN_WING_FRACTION",
    "ProfileRefinement",
    "refine_with_profile",
]

FloatArray = NDArray[np.float64]

#: Half-width of each vertex's strip along its normal, pixels: the pixel
#: box, a blur of up to 1.5 px and the walk from the DT lock fit inside,
#: and the far interior (where a wrong law would weigh most) stays out.
HALF_WIDTH_PX = 3.5

#: A strip reaches at most this far along the edge from its vertex (pixels;
#: otherwise half the distance to each neighbour, so that strips tile the
#: polyline). The pixel model reads the edge as a circle of the vertex's
#: curvature, to second order in the distance along the edge; a sparse
#: polyline's strips (3 vertices on a limb: tens of pixels) reach where that
#: reading is off, and their many pixels then pin the offset along the edge
#: to a wrong place with a tiny sigma.
MAX_TAU_PX = HALF_WIDTH_PX

#: A refinement needs at least this many vertices (with contrast): with 3-4,
#: a few short strips carry the whole pose, and the property sweeps found such
#: fits ``ok`` and 1.0-2.4 px off at one-sigmas of 0.02-0.31 px (limbs and
#: terminators, with the PSF's wings or light noise), where no fit of 5 or
#: more vertices was more than 1 px off (docs/profiles.rst, "Property sweeps").
MIN_VERTICES = 5

#: A refinement that moves the offset farther than this from the DT-LM
#: lock is discarded: the DT's photometric bias reaches ~0.75 px at
#: moderate phase and ~1.2 px at low phase, so a longer walk means the
#: model does not describe the image.
MAX_WALK_PX = 2.0

#: The terminator's start: the DT puts a Lambert terminator (a kink in
#: brightness, not an edge) where the brightness ramp crosses the edge
#: threshold, 4-15 px on the lit side of the geometric terminator on the
#: rendered scenes (:ref:`profiles-terminator`), beyond the strip's reach.
#: So a terminator's refinement starts from a scan of the profile model
#: along the polyline's mean normal, from this far on the dark side of the
#: DT lock ...
SCAN_DARK_PX = 20.0
#: ... to this far on its lit side ...
SCAN_LIT_PX = 4.0
#: ... in steps of this (a seventh of the strip's 7 px width: the
#: correlation's peak spans several steps), refined by a parabola through
#: the best three.
SCAN_STEP_PX = 0.5

#: A terminator's fit that lands more than :data:`TERMINATOR_CENTRED_PX`
#: from its strips' centre (the scan places the start along the mean normal
#: only: at high phase the DT lock is also off across it) is run again from
#: where it went, with the strips centred there, at most this many times in
#: all; the walk limit :data:`MAX_WALK_PX` holds for the last run.
TERMINATOR_RECENTRES = 6

#: ... until it lands within this of their centre, pixels: a kink off the
#: strips' centre leaves one side of it short (1.5 px of the 3.5 px
#: half-width at a 2 px walk), and the dark side is what tells the kink's
#: position from the gain and background (fits stopped about 1 px off
#: their strips' centre were among those more than 1 px off the truth:
#: :ref:`profiles-terminator`). About a tenth of the half-width.
TERMINATOR_CENTRED_PX = 0.3

#: An accepted refinement of a fit whose DT stage found an ambiguous rival
#: basin is run again from the rival's DT-LM pose; when it lands within
#: this many of the refinement's one-sigma (its covariance plus the
#: profile floor, the largest axis) of the same offset, the image itself
#: decides between the two basins and the fit is not ``ambiguous``. Two
#: sigmas keeps the starts that agree on rendered terminators and leaves
#: out a refinement that lands far from its rival's
#: (docs/profiles.rst, "Rival basins").
RIVAL_AGREEMENT_SIGMAS = 2.0

#: Table margin beyond the strip, pixels: the walk the table still models
#: exactly (beyond it the profile is held flat).
TABLE_MARGIN_PX = 2.5

#: Gauss-Newton iteration cap and step tolerance (pixels): a tenth of the
#: accuracy the refinement is for (0.01 px median); the Tukey weights of a
#: renderer's sampled pixels settle slowly below that.
MAX_ITERATIONS = 50
TOLERANCE_PX = 1e-4

#: A terminator's PSF sigma, when the profile does not give it, is fitted
#: once more with the offset on every vertex after the strips are placed
#: (:func:`refine_with_profile`), not held at its estimate on
#: ``SIGMA_VERTICES`` vertices as a limb's is: a kink's blur only
#: rounds its toe, which a shift of the kink does too, so the offset moves
#: with the sigma (0.4-0.8 px per 0.5 px of sigma on the rendered
#: terminators of :ref:`profiles-terminator`), and on the fits that the
#: slope and the centring left more than 1 px off the subset's sigma was
#: 0.9-1.6 px too wide, where a narrower one fitted all the pixels better.
#: The refinement's covariance then includes the sigma's uncertainty.
TERMINATOR_FREE_SIGMA = True

#: Tukey cutoff of the refinement, in residual scales (the 95 %-efficient value).
TUKEY_C = 4.685

#: Fit a background slope along the normals: scattered light (a PSF's
#: wings, a glow around a bright disc) is a ramp across the strip, which a
#: flat background would hand to the edge's position. Not for a terminator:
#: its lit side is itself a ramp, so a background ramp trades with the gain
#: and moves the kink (only the strips' dark half tells them apart); on the
#: rendered terminators the fits more than 1 px off had fitted a slope of
#: 0.3-1.3 DN/px and a gain of 54-163 DN where the albedo was 200 DN
#: (:ref:`profiles-terminator`).
FIT_SLOPE = True


#: Step tolerance (pixels, and pixels of sigma) of the sigma's estimate:
#: the offset is fitted again, on every vertex, with the sigma held.
SIGMA_TOLERANCE = 1e-3

#: Starting PSF sigma (pixels) when the profile does not give it.
SIGMA_START_PX = 0.7

#: Fit the PSF's wings: a fraction of the light in a second, wider Gaussian
#: (scattered light in the optics), estimated with the PSF on a subset of
#: about 48 vertices and then held; a core sigma given by the
#: profile is the core's. Not for a terminator (its start is a scan whose
#: strips are placed with the core alone; see :ref:`profiles-terminator`).
FIT_WINGS = True

#: The wings' start: this fraction of the light (a weak halo; not 0, where
#: the wing sigma would have no gradient) ...
WING_FRACTION_START = 0.05
#: ... in a Gaussian of this sigma (pixels; a few pixels, inside the strip
#: of +-3.5 px, and at least ``MIN_WING_RATIO`` core sigmas) ...
WING_SIGMA_START_PX = 3.0
#: ... whose sigma is fitted too (else held at its start).
FIT_WING_SIGMA = True

#: Wings with less of the light than this are dropped (the full run then
#: starts as it would without them): ignoring wings moves the edge by about
#: 0.8 px per unit of their fraction (0.16 px at 20 %, on the rendered
#: scenes of :ref:`profiles-bias-table`), under 0.004 px here, and folding
#: them into the profile costs a fraction of the fit.
MIN_WING_FRACTION = 0.005

#: The PSF sigma is estimated on about this many vertices (every k-th),
#: then held while the offset is fitted on all of them: the estimate's
#: cost is then independent of the polyline's length.
SIGMA_VERTICES = 48

#: A limb's vertex whose profile's contrast across its strip (the table's
#: range) is at most this fraction of the polyline's largest is left out of
#: the refinement (counted in ``ProfileRefinement.n_flat_vertices``): its
#: pixels say nothing of the edge, only of the background, which an unlit
#: part of a limb would then set (and bias, where the night side is not at
#: the sky's level; the lit vertices' sky side measures it). Not a
#: terminator's: its dark horns are the dark side that fixes its background
#: against its gain.
FLAT_CONTRAST = 1e-3

#: A terminator's vertex whose profile, past its brightest value on the lit
#: side of its strip, falls back below this fraction of it has the limb
#: within its strip: a horn of the crescent, where the 1-D model across the
#: terminator (the terminator's curvature for every pixel of the strip) does
#: not describe the limb that cuts it.
HORN_FRACTION = 0.5

#: A terminator's accepted refinement is refitted without its horns
#: (:data:`HORN_FRACTION`) from its own pose; a shift of the pose along the
#: polyline's mean normal beyond this many sigmas of the shift (the larger of
#: the two fits' sigmas along it: the difference of their variances, the
#: figure for nested fits of the same pixels, collapses to 0 when their
#: residual scales differ, and flagged honest fits) and beyond
#: :data:`HORN_SHIFT_MIN_PX` is
#: ``ProfileRefinement.horn_shift_px`` that :func:`misfitted` reports: the
#: horns and the rest of the terminator put the edge in different places.
#: Under Lommel-Seeliger the horns are bright (``cos i / (cos i + cos e)``
#: stays near 1/2 as both cosines vanish), and a crescent's terminator at
#: phase 100-110 deg, its blur estimated, lay 0.3-1.6 px off at 4-10 sigma
#: with the horns, 0.07-0.3 px without (docs/profiles.rst, "A
#: terminator's horns").
HORN_SHIFT_SIGMAS = 2.5
#: See :data:`HORN_SHIFT_SIGMAS`.
HORN_SHIFT_MIN_PX = 0.1

#: A terminator's night side above the sky. The profile's night side is dark
#: (0), and the refinement's free background takes whatever level it has.
#: Lit by the planet or a ring (additive), the kink stays where it was; floored
#: (``max(shading, floor)``: an ambient term, a simulator's or a stray
#: light's), the kink moves to where the shading reaches the floor, toward the
#: lit side. The two give the same strips to first order, so the fit cannot
#: tell them apart; its covariance holds the difference instead
#: (``ProfileRefinement.night_shift_vu``; docs/profiles.rst, "A night side
#: above the sky"). The sky is read around the polyline at the fitted pose,
#: this far beyond its vertices' box, px (the region a fit reads holds it:
#: :mod:`dtalign.pipeline.region`) ...
NIGHT_BOX_PX = 32.0
#: ... in blocks of this many pixels a side, whose means average the noise ...
NIGHT_BLOCK_PX = 4
#: ... as this quantile of the blocks' means, corrected by the noise of a
#: block's mean (the blocks' own spread, among the darkest): the sky is the
#: darkest population around a body.
NIGHT_SKY_QUANTILE = 0.05
#: The night side is lit when it lies above that sky by more than this many
#: of a block mean's noise ...
NIGHT_SIGMAS = 3.0
#: ... and by more than this fraction of the fitted gain (a noise-free image's
#: numerical level moves the kink by less than a hundredth of a pixel).
NIGHT_MIN_FRACTION = 1e-3

#: The bins of distance past the edge, px, in which :func:`misfit` takes
#: the median residual of the pooled strips.
MISFIT_BIN_PX = 0.5

#: An accepted refinement whose ``ProfileRefinement.misfit`` exceeds
#: this fraction of its gain leaves a shape its model does not have (the
#: status's ``profile_misfit``). Measured on the validation renders
#: (docs/validation.rst): model-right limbs and terminators, the PSF
#: estimated, leave at most 0.002; a Minnaert surface fitted as Lambert
#: 0.02, craters 0.007, a capped brightening 0.8.
MISFIT_LIMIT = 0.004

#: The residual shape :func:`misfit` reports is what exceeds the noise's
#: share of the bins' squared medians by this many of its standard
#: deviations: a heavy noise's chance shape is not a model's error.
MISFIT_NOISE_SIGMAS = 3.0

#: An accepted refinement whose vertices' edges spread about its pose by
#: more than this beyond the noise, px (``sqrt(scatter^2 - noise^2)`` of
#: ``ProfileRefinement.edge_scatter_px`` and
#: ``ProfileRefinement.edge_noise_px``), and by more than
#: :data:`SCATTER_RATIO` times the noise, fits a surface whose edge the
#: model does not hold (relief, craters): ``profile_misfit``.
SCATTER_LIMIT_PX = 0.03
#: See :data:`SCATTER_LIMIT_PX`. The noise's share is read from the
#: residuals of all the strips' pixels, most of them on the sky, so it is a
#: little low where the signal's shot noise dominates: model-right noisy
#: limbs read up to 1.5.
SCATTER_RATIO = 1.6

#: An accepted refinement whose vertices' own gains spread by more than this
#: fraction of its gain beyond the noise (``sqrt(scatter^2 - noise^2)`` of
#: ``ProfileRefinement.gain_scatter`` and ``ProfileRefinement.gain_noise``),
#: and by more than :data:`SCATTER_RATIO` times the noise, fits one gain to a
#: surface whose brightness varies along the edge (an albedo map, craters):
#: ``profile_misfit``. On the validation renders the honest fits (the model
#: right, the PSF mismatched and estimated, the ellipsoid, a lit or floored
#: night side, heavy noise; limbs and terminators) leave at most 0.0085
#: beyond the noise where their spread exceeds 1.6 of it; an albedo map of
#: +-25 % leaves 0.035-0.17.
GAIN_SCATTER_LIMIT = 0.015

#: A limb profile whose contrast-weighted median ``EdgeProfile.step_jump``
#: is below this has no usable edge: its brightness rolls off to the edge
#: (a Lambert limb below ~10-15 deg phase), so the edge's position rests on
#: the roll-off's modelled shape alone.
SOFT_EDGE_STEP_JUMP = 0.25


@dataclass(frozen=True)
class ProfileRefinement:
    """Outcome of the profile refinement of one polyline fit.

    Attributes
    ----------
    offset_vu : tuple of float
        The refined offset (whether accepted or not).
    dt_offset_vu : tuple of float
        The DT-LM offset.
    accepted : bool
        True when the fit's pose is this refinement's.
    reason : str
        Why it was discarded (empty when accepted).
    gain, background, background_slope : float
        The fitted photometric scale, sky level (image units) and the sky's
        slope along the normals (image units per pixel; 0 for a terminator,
        whose slope is not fitted: ``FIT_SLOPE``).
    shape_amplitude : float
        The fitted amplitude of the profile's shape basis (0 without one;
        for :func:`~dtalign.sphere_edge_profile`, the change of Minnaert's
        exponent from the law given, to first order).
    psf_sigma_px : float
        The PSF sigma used (given, or estimated).
    psf_estimated : bool
        True when ``psf_sigma_px`` was estimated.
    wing_fraction, wing_sigma_px : float
        The PSF's wings, estimated (:data:`FIT_WINGS`): this fraction of the
        light in a Gaussian of this sigma, the rest in the core of
        ``psf_sigma_px``; a fraction of 0 and a sigma of NaN when none
        were fitted or found.
    iterations : int
        Gauss-Newton iterations (both stages when the sigma was estimated).
    converged : bool
        The last step fell below the tolerance.
    walk_px : float
        Distance from the DT-LM offset to the refined one.
    n_pixels : int
        Pixels fitted.
    residual_scale : float
        1.4826 MAD of the final residuals (image units), as the pixels give
        it; NaN when not measured (no pixels, a gain that is not positive).
    covariance : tuple of tuple of float
        2 x 2 covariance of the offset from the weighted information and
        the Tukey weights' residual scale, which is floored at the kernels'
        ``SCALE_FLOOR`` of the gain, the model's per-pixel accuracy
        (pixels^2): where the pixels fix the pose weakly, a model error
        that leaves no residual moves it that much. The model's common
        error is the pipeline's floor, which its covariance adds
        (:mod:`dtalign.pipeline.uncertainty`).
    step_jump : float
        The profile's contrast-weighted median step fraction.
    soft_edge : bool
        A limb profile with no usable edge (step fraction below
        :data:`SOFT_EDGE_STEP_JUMP`); never set for other edge kinds.
    time_s : float
        Wall time of the refinement.
    n_flat_vertices : int
        Vertices left out because their profile has no contrast across the
        strip (:data:`FLAT_CONTRAST`: an unlit part of a limb).
    horn_shift_px, horn_shift_sigma_px : float
        A terminator's: how far its pose moves along the polyline's mean
        normal when refitted without the vertices whose strips the limb cuts
        (the crescent's horns: :data:`HORN_SHIFT_SIGMAS`), and the sigma of
        that shift; NaN when not measured (not a terminator, no horns, too
        few vertices without them, or a rejected refinement).
    misfit : float
        What the fitted model leaves that the noise does not
        (:func:`misfit`): the median residual of the strips' pixels in each
        :data:`MISFIT_BIN_PX` bin of distance past the edge, pooled over
        the vertices so that the noise averages away, its root mean square
        over the bins, as a fraction of the fitted gain. A model that is
        right leaves a few thousandths; a reflectance law, a surface or a
        PSF that differ from the declared leave a systematic shape, which
        above :data:`MISFIT_LIMIT` makes the fit suspect
        (``profile_misfit``). NaN when not measured.
    edge_scatter_px, edge_noise_px : float
        The robust spread of the vertices' own edge positions about the
        fitted pose, along their normals, px, and the spread the residuals'
        noise explains (:func:`misfit`): a surface whose relief or texture
        moves the edge from vertex to vertex spreads them beyond the noise,
        which :data:`SCATTER_LIMIT_PX` and :data:`SCATTER_RATIO` flag
        (``profile_misfit``). NaN when not measured.
    gain_scatter, gain_noise : float
        The robust spread of the vertices' own gains (each fitted with its
        shift and background on its strip) as a fraction of the fitted gain,
        and the spread the residuals' noise explains (:func:`misfit`): an
        albedo that varies along the edge, or a surface whose brightness
        does, spreads them beyond the noise, which :data:`GAIN_SCATTER_LIMIT`
        and :data:`SCATTER_RATIO` flag (``profile_misfit``). NaN when not
        measured.
    night_level : float
        A terminator's: its fitted background (the night side's level) less
        the sky's around it (:data:`NIGHT_BOX_PX`), image units; NaN when not
        measured (not a terminator, a rejected refinement, too little image
        around it).
    night_shift_vu : tuple of float or None
        A terminator whose night side is lit (``night_level`` beyond
        :data:`NIGHT_SIGMAS` of its noise and :data:`NIGHT_MIN_FRACTION` of
        the gain): how far, along the polyline's mean normal toward the lit
        side, a night side floored at that level rather than lit would have
        moved the fitted kink (where the profile, times the gain, reaches
        the level). The pipeline's covariance adds it (``night_side_lit``);
        None otherwise.
    start_offset_vu : tuple of float or None
        Where the Gauss-Newton started when not at the DT-LM offset: a
        terminator's scan (:data:`SCAN_DARK_PX`); None otherwise. A
        terminator's walk limit :data:`MAX_WALK_PX` is measured from where
        its last run started (:data:`TERMINATOR_RECENTRES`); ``walk_px``
        stays the distance from the DT-LM offset.
    rival_offset_vu : tuple of float or None
        Where the same refinement lands when started from the DT-LM pose of
        the fit's rival basin, for an accepted refinement of a fit whose
        DT stage was ambiguous (``dtalign.pipeline.fit.refined``);
        None otherwise.
    rival_agrees : bool or None
        Whether it lands on this refinement's offset (within
        :data:`RIVAL_AGREEMENT_SIGMAS` of its one-sigma): the image then
        decides between the two basins, and the fit is not ``ambiguous``.
        None when not tried.
    """

    offset_vu: tuple[float, float]
    dt_offset_vu: tuple[float, float]
    accepted: bool
    reason: str
    gain: float
    background: float
    background_slope: float
    shape_amplitude: float
    psf_sigma_px: float
    psf_estimated: bool
    iterations: int
    converged: bool
    walk_px: float
    n_pixels: int
    residual_scale: float
    covariance: tuple[tuple[float, float], tuple[float, float]]
    step_jump: float
    soft_edge: bool
    time_s: float
    start_offset_vu: tuple[float, float] | None = None
    rival_offset_vu: tuple[float, float] | None = None
    rival_agrees: bool | None = None
    wing_fraction: float = 0.0
    wing_sigma_px: float = math.nan
    n_flat_vertices: int = 0
    horn_shift_px: float = math.nan
    horn_shift_sigma_px: float = math.nan
    misfit: float = math.nan
    edge_scatter_px: float = math.nan
    edge_noise_px: float = math.nan
    gain_scatter: float = math.nan
    gain_noise: float = math.nan
    night_level: float = math.nan
    night_shift_vu: tuple[float, float] | None = None

    #: JSON's None reads back as NaN (:mod:`dtalign.pipeline.records`).
    NONFINITE: ClassVar[float] = math.nan

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict of the fields (a value that is not finite is
        ``None``); :meth:`from_dict` reads it back."""
        return to_json(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ProfileRefinement:
        """The refinement :meth:`to_dict` wrote (``None`` reads as NaN)."""
        return from_json(cls, d)


def check_edge_profile(value: Any, normals_vu: FloatArray) -> EdgeProfile:
    """``value`` as the :class:`~dtalign.api.profiles.EdgeProfile` of a polyline with these normals."""
    if not isinstance(value, EdgeProfile):
        raise TypeError(f"edge_profile must be a dtalign.EdgeProfile, got {type(value).__name__}")
    n = normals_vu.shape[0]
    if value.n_vertices != n:
        raise ValueError(f"edge_profile has {value.n_vertices} vertices, the polyline {n}")
    dots = (value.normals_vu * normals_vu).sum(axis=1)
    if (dots < 0.5).any():
        k = int(np.argmin(dots))
        raise ValueError(
            f"edge_profile normal {k} points away from the polyline's normal (cosine "
            f"{dots[k]:.3g}): the profile must run along the polyline's normals"
        )
    return value


def edge_kind_of(edge_kind: Any, profile: EdgeProfile | None) -> str | None:
    """The kind of edge a polyline is: ``edge_kind`` (one of
    :data:`~dtalign.api.profiles.EDGE_KINDS`, or None: not declared), or
    the checked ``profile``'s ``edge`` when ``edge_kind`` is None.

    Raises
    ------
    ValueError
        If ``edge_kind`` is not an edge kind, or differs from the profile's ``edge``.
    """
    if edge_kind is not None and (not isinstance(edge_kind, str) or edge_kind not in EDGE_KINDS):
        raise ValueError(f"edge_kind must be one of {EDGE_KINDS} or None, got {edge_kind!r}")
    if profile is None:
        return edge_kind
    if edge_kind is not None and edge_kind != profile.edge:
        raise ValueError(f"edge_kind {edge_kind!r} conflicts with edge_profile.edge "
                         f"{profile.edge!r}: give one kind (or leave edge_kind None)")
    return profile.edge


def _tau_max(verts: FloatArray) -> FloatArray:
    n = verts.shape[0]
    if n == 1:
        return np.full(1, 0.5)
    seg = np.hypot(*np.diff(verts, axis=0).T)
    left = np.concatenate(([seg[0]], seg))
    right = np.concatenate((seg, [seg[-1]]))
    return np.asarray(np.minimum(0.25 * (left + right), MAX_TAU_PX), dtype=np.float64)


def _rotated(points: FloatArray, angle: float, pivot: tuple[float, float] | None) -> FloatArray:
    c, s = math.cos(angle), math.sin(angle)
    rot = np.array([[c, -s], [s, c]])
    if pivot is None:
        return np.ascontiguousarray(points @ rot.T)
    p = np.asarray(pivot)
    return np.ascontiguousarray((points - p) @ rot.T + p)


def _weighted_median(x: FloatArray, w: FloatArray) -> float:
    if w.sum() <= 0.0:
        return float(np.median(x))
    order = np.argsort(x)
    cw = np.cumsum(w[order])
    return float(x[order][np.searchsorted(cw, 0.5 * cw[-1])])


def refine_with_profile(
    image: FloatArray,
    profile: EdgeProfile,
    vertices_vu: FloatArray,
    dt_offset_vu: tuple[float, float],
    *,
    rotation_rad: float = 0.0,
    pivot_vu: tuple[float, float] | None = None,
    kernels: Any = None,
    mask: NDArray[np.bool_] | None = None,
) -> ProfileRefinement:
    """Refine a DT-LM offset against ``image`` with ``profile`` (see the module).

    Parameters
    ----------
    image : ndarray, shape (H, W)
        The checked float64 image.
    profile : EdgeProfile
        Checked against the polyline by :func:`check_edge_profile`.
    vertices_vu : ndarray, shape (N, 2)
        The model vertices (before the pose).
    dt_offset_vu : tuple of float
        The DT-LM offset, the start.
    rotation_rad, pivot_vu
        The DT-LM rotation and its pivot: held fixed.
    kernels : module, optional
        The implementation: ``dtalign._kernels.profile`` (default) or
        :mod:`dtalign.reference.profile`.
    mask : ndarray of bool, shape (H, W), optional
        Bad pixels (``ImageProducts.mask``): the strips' pixels on them are
        left out of every fit and scan, as if outside the image.

    Returns
    -------
    ProfileRefinement
    """
    if kernels is None:
        kernels = loop.profile_kernels
    t_start = time.perf_counter()
    pb = _problem(image, profile, vertices_vu, dt_offset_vu, rotation_rad, pivot_vu, kernels)
    if mask is not None:
        pb = pb._replace(mask=mask)
    # contrast-weighted step fraction: is there an edge at all?
    contrast = np.ptp(pb.values[:, pb.j0 : pb.j0 + pb.nb], axis=1)
    step_jump = _weighted_median(np.asarray(profile.step_jump), contrast)
    # only a limb is meant to step: a terminator is a kink (cos i through 0), a ring's
    # profile whatever its model says, and neither is soft for lacking a step
    soft = profile.edge == "limb" and step_jump < SOFT_EDGE_STEP_JUMP
    flat = contrast <= FLAT_CONTRAST * contrast.max(initial=0.0)
    if profile.edge != "limb":
        # a terminator's dark horns are its dark side, which fixes the
        # background against the gain (its slope is not fitted)
        flat[:] = flat.all()
    try:
        if flat.all():
            raise _Unusable("no vertex's profile has any contrast across its strip", 0)
        if flat.any():
            pb = _kept(pb, ~flat)
        if pb.verts.shape[0] < MIN_VERTICES:
            raise _Unusable(f"too few vertices for the photometric fit ({pb.verts.shape[0]}, "
                            f"at least {MIN_VERTICES}): a few strips do not average the "
                            "model's errors", 0)
        ref = _refine(pb, profile, dt_offset_vu, step_jump, soft, t_start)
        return dataclasses.replace(ref, n_flat_vertices=int(flat.sum()))
    except _Unusable as exc:
        dt = (float(dt_offset_vu[0]), float(dt_offset_vu[1]))
        nan = math.nan
        return ProfileRefinement(
            offset_vu=dt, dt_offset_vu=dt, accepted=False, reason=str(exc), gain=nan,
            background=nan, background_slope=nan, shape_amplitude=nan, psf_sigma_px=nan,
            psf_estimated=profile.psf_sigma_px is None, iterations=0, converged=False,
            walk_px=0.0, n_pixels=exc.n_pixels, residual_scale=nan,
            covariance=((nan, nan), (nan, nan)), step_jump=float(step_jump), soft_edge=bool(soft),
            time_s=time.perf_counter() - t_start, n_flat_vertices=int(flat.sum()),
        )


def _horns(pb: _Problem) -> NDArray[np.bool_]:
    """The vertices of a terminator whose profile, within the strips' reach,
    falls past its brightest value toward the lit side (the offsets' end)
    below :data:`HORN_FRACTION` of it: the limb cuts their strips."""
    vals = pb.values[:, pb.j0 : pb.j0 + pb.nb]
    if vals.shape[1] == 0:
        return np.zeros(vals.shape[0], dtype=bool)
    peak = np.argmax(vals, axis=1)
    top = vals[np.arange(vals.shape[0]), peak]
    after = np.where(np.arange(vals.shape[1])[None, :] >= peak[:, None], vals, np.inf)
    return np.asarray((top > 0.0) & (after.min(axis=1) < HORN_FRACTION * top))


def _horn_shift(pb: _Problem, params: FloatArray, cov: FloatArray, known: bool
                ) -> tuple[float, float]:
    """A terminator's pose shift along the polyline's mean normal when its last
    run (``pb`` from ``params``, its offset's covariance ``cov``) is repeated
    without its horns (:func:`_horns`), and that shift's sigma
    (:data:`HORN_SHIFT_SIGMAS`); NaN, NaN when there are no horns, fewer than
    :data:`MIN_VERTICES` vertices without them, or the run cannot be made."""
    horn = _horns(pb)
    nbar = pb.normals.sum(axis=0)
    norm = math.hypot(float(nbar[0]), float(nbar[1]))
    if not horn.any() or int((~horn).sum()) < MIN_VERTICES or not norm > 0.0:
        return math.nan, math.nan
    nbar = nbar / norm
    try:
        p_h, _, _, inv_h, scale_h, _, _ = _run(_kept(pb, ~horn), None, params, not known,
                                               TOLERANCE_PX)
    except _Unusable:
        return math.nan, math.nan
    cov_h = np.asarray(inv_h)[:2, :2] * float(scale_h) ** 2
    shift = float((np.asarray(p_h)[:2] - params[:2]) @ nbar)
    if not (math.isfinite(shift) and np.isfinite(cov_h).all() and np.isfinite(cov).all()):
        return math.nan, math.nan
    var = max(float(nbar @ cov_h @ nbar), float(nbar @ cov @ nbar))
    return shift, math.sqrt(max(var, 0.0))


def _sky(pb: _Problem, verts: FloatArray) -> tuple[float, float] | None:
    """The sky's level around ``verts`` (:data:`NIGHT_BOX_PX`), image units,
    and the noise of a block's mean: the :data:`NIGHT_SKY_QUANTILE` of the
    :data:`NIGHT_BLOCK_PX` blocks' means, raised by that quantile of a block
    mean's noise (the median spread within the darkest tenth of the blocks,
    over the block's side); None when fewer than 20 blocks free of bad pixels
    fit."""
    hgt, wid = pb.image.shape
    lo = np.clip(np.floor(verts.min(axis=0) - NIGHT_BOX_PX), 0, (hgt, wid)).astype(np.int64)
    hi = np.clip(np.ceil(verts.max(axis=0) + NIGHT_BOX_PX), 0, (hgt, wid)).astype(np.int64)
    b = NIGHT_BLOCK_PX
    nv, nu = (int(hi[0] - lo[0]) // b, int(hi[1] - lo[1]) // b)
    if nv * nu < 20:
        return None
    box = pb.image[lo[0]:lo[0] + nv * b, lo[1]:lo[1] + nu * b]
    blocks = box.reshape(nv, b, nu, b).transpose(0, 2, 1, 3).reshape(nv * nu, b * b)
    if pb.mask is not None:
        bad = pb.mask[lo[0]:lo[0] + nv * b, lo[1]:lo[1] + nu * b]
        good = ~bad.reshape(nv, b, nu, b).transpose(0, 2, 1, 3).reshape(nv * nu, b * b).any(1)
        blocks = blocks[good]
    if blocks.shape[0] < 20:
        return None
    means = blocks.mean(axis=1)
    darkest = means <= np.quantile(means, 0.1)
    noise = float(np.median(blocks[darkest].std(axis=1, ddof=1))) / b
    # the quantile of a Gaussian's: 1.645 of its sigmas below its mean
    return float(np.quantile(means, NIGHT_SKY_QUANTILE)) + 1.645 * noise, noise


def _night_side(pb: _Problem, params: FloatArray) -> tuple[float, tuple[float, float] | None]:
    """A terminator's ``(night_level, night_shift_vu)`` at its fitted
    ``params`` (``ProfileRefinement``): NaN and None when not measured."""
    verts = pb.verts + params[:2]
    measured = _sky(pb, verts)
    if measured is None:
        return math.nan, None
    sky, noise = measured
    gain, level = float(params[2]), float(params[3]) - sky
    nbar = pb.normals.sum(axis=0)
    norm = math.hypot(float(nbar[0]), float(nbar[1]))
    if not (gain > 0.0 and math.isfinite(level) and norm > 0.0):
        return math.nan, None
    if not (level > NIGHT_SIGMAS * noise and level > NIGHT_MIN_FRACTION * gain):
        return level, None
    # where each vertex's model (the fitted shape amplitude included) first
    # reaches the level past the kink: a floor there is the kink it fits
    vals = pb.values + params[5] * pb.shape if pb.use_shape else pb.values
    offsets = pb.o0 + pb.h * np.arange(vals.shape[1])
    past = offsets >= 0.0
    off, rows = offsets[past], vals[:, past] - level / gain
    first = np.argmax(rows >= 0.0, axis=1)
    reached = rows[np.arange(rows.shape[0]), first] >= 0.0
    prev = np.maximum(first - 1, 0)
    a, c = rows[np.arange(rows.shape[0]), prev], rows[np.arange(rows.shape[0]), first]
    frac = np.where((first > 0) & (c > a), -a / np.where(c > a, c - a, 1.0), 0.0)
    cross = np.where(reached, off[prev] + frac * (off[first] - off[prev]), off[-1])
    shift = float(np.median(cross)) / norm
    return level, (float(nbar[0] * shift), float(nbar[1] * shift))


def _kept(pb: _Problem, keep: NDArray[np.bool_]) -> _Problem:
    """``pb`` over the vertices ``keep`` only (each keeps its strip's length)."""
    def sub(a: FloatArray) -> FloatArray:
        return np.ascontiguousarray(a[keep])

    return pb._replace(verts=sub(pb.verts), normals=sub(pb.normals), curv=sub(pb.curv),
                       values=sub(pb.values), shape=sub(pb.shape), tau=sub(pb.tau))


class _Unusable(Exception):
    """A refinement that cannot be computed (too few pixels, a model or a
    system that is not finite or not solvable): :func:`refine_with_profile`
    returns it as a rejected refinement whose reason is this message."""

    def __init__(self, reason: str, n_pixels: int) -> None:
        super().__init__(reason)
        self.n_pixels = n_pixels


def _refine(pb: _Problem, profile: EdgeProfile, dt_offset_vu: tuple[float, float],
            step_jump: float, soft: bool, t_start: float) -> ProfileRefinement:
    """The body of :func:`refine_with_profile`; raises :class:`_Unusable`."""
    known = profile.psf_sigma_px is not None
    sigma = SIGMA_START_PX if profile.psf_sigma_px is None else float(profile.psf_sigma_px)
    start = None
    if profile.edge == "terminator" and pb.verts.shape[0] > 0:
        start = _scan_start(pb, sigma)
        pb = pb._replace(d0=start)
    d0 = pb.d0
    params = _start(d0, sigma, wings := FIT_WINGS and start is None)
    iterations = 0
    if start is not None and not known:
        # a terminator's strips are placed first, with the sigma held at its
        # start: estimated 2-5 px from the kink (the scan's start at high
        # phase), the sigma would absorb the misplacement
        pb, _, placed = _recentred(pb, params)
        iterations += int(placed[1])
        if placed[2]:
            pb = pb._replace(d0=(float(placed[0][0]), float(placed[0][1])))
        d0 = pb.d0
        params = _start(d0, sigma, False)
    if (wings or not known) and pb.verts.shape[0] > 0:
        params, it_a = _estimate_psf(pb, params, not known, wings)
        iterations += it_a
    if start is None:
        out = _run(_with_wings(pb, params), None, params, False, TOLERANCE_PX)  # PSF held
    else:
        pb, out = _terminator_fit(pb, params, known)
    p, it, conv, inv, scale, _, npx = out
    iterations += int(it)
    d0 = pb.d0
    off = (float(p[0]), float(p[1]))
    walk = math.hypot(off[0] - d0[0], off[1] - d0[1])
    # at the Tukey weights' scale, floored at the model's per-pixel accuracy:
    # where the pixels fix the pose weakly, a model error that leaves no
    # residual moves it by this much (docs/uncertainty.rst, part 1)
    cov = np.asarray(inv)[:2, :2] * float(scale) ** 2
    reason = _rejection(int(npx), bool(conv), iterations, walk, float(p[2]), cov,
                        "the DT lock" if start is None else "where its last run started")
    dt = (float(dt_offset_vu[0]), float(dt_offset_vu[1]))
    if start is not None:
        walk = math.hypot(off[0] - dt[0], off[1] - dt[1])
    final = pb if start is not None else _with_wings(pb, params)
    left = misfit(final, np.asarray(p, dtype=np.float64))
    horn_shift = horn_sigma = night_level = math.nan
    night_shift = None
    if start is not None and not reason:
        horn_shift, horn_sigma = _horn_shift(pb, np.asarray(p, dtype=np.float64), cov, known)
        night_level, night_shift = _night_side(pb, np.asarray(p, dtype=np.float64))
    return ProfileRefinement(
        offset_vu=off, dt_offset_vu=dt, accepted=not reason, reason=reason,
        gain=float(p[2]), background=float(p[3]), background_slope=float(p[6]),
        shape_amplitude=float(p[5]),
        psf_sigma_px=float(p[4]), wing_fraction=float(params[7]),
        wing_sigma_px=float(params[8]) if params[7] > 0.0 else math.nan,
        psf_estimated=not known, iterations=iterations, converged=bool(conv), walk_px=walk,
        n_pixels=int(npx), residual_scale=float(left.residual_scale),
        covariance=((float(cov[0, 0]), float(cov[0, 1])), (float(cov[1, 0]), float(cov[1, 1]))),
        step_jump=float(step_jump), soft_edge=bool(soft),
        time_s=time.perf_counter() - t_start, start_offset_vu=start,
        misfit=left.misfit, edge_scatter_px=left.edge_scatter_px,
        edge_noise_px=left.edge_noise_px, gain_scatter=left.gain_scatter,
        gain_noise=left.gain_noise,
        horn_shift_px=horn_shift, horn_shift_sigma_px=horn_sigma,
        night_level=night_level, night_shift_vu=night_shift,
    )


def misfitted(ref: ProfileRefinement) -> bool:
    """Whether an accepted refinement leaves what its model does not explain: a
    shape (:data:`MISFIT_LIMIT`), a spread of its vertices' edges beyond the
    noise (:data:`SCATTER_LIMIT_PX`, :data:`SCATTER_RATIO`) or of their gains
    (:data:`GAIN_SCATTER_LIMIT`), or a terminator's
    horns that move its pose (:func:`horns_disagree`). False when not
    measured (NaN) or not accepted."""
    if not ref.accepted:
        return False
    return bool(ref.misfit > MISFIT_LIMIT or _beyond(ref.edge_scatter_px, ref.edge_noise_px,
                                                     SCATTER_LIMIT_PX)
                or _beyond(ref.gain_scatter, ref.gain_noise, GAIN_SCATTER_LIMIT)
                or horns_disagree(ref))


def _beyond(scatter: float, noise: float, limit: float) -> bool:
    """A spread beyond :data:`SCATTER_RATIO` times the noise's, and beyond ``limit``
    once the noise's is taken out (``sqrt(scatter^2 - noise^2)``); False for NaN."""
    return bool(scatter > SCATTER_RATIO * noise
                and math.sqrt(max(scatter * scatter - noise * noise, 0.0)) > limit)


def horns_disagree(ref: ProfileRefinement) -> bool:
    """Whether a terminator's horns move its pose (``horn_shift_px`` beyond
    :data:`HORN_SHIFT_SIGMAS` of its sigma and :data:`HORN_SHIFT_MIN_PX`);
    False when not measured."""
    shift, sigma = abs(ref.horn_shift_px), ref.horn_shift_sigma_px
    return bool(shift > HORN_SHIFT_MIN_PX and shift > HORN_SHIFT_SIGMAS * sigma)


class Misfit(NamedTuple):
    """What a refinement's parameters leave on its strips (:func:`misfit`);
    each field is the :class:`ProfileRefinement` attribute of its name."""

    misfit: float
    edge_scatter_px: float
    edge_noise_px: float
    gain_scatter: float
    gain_noise: float
    residual_scale: float


def misfit(pb: _Problem, params: FloatArray) -> Misfit:
    """What ``params`` leave on ``pb``'s strips (those of the refinement's last
    run, its PSF's wings folded into the profile).

    ``misfit`` is the RMS over the :data:`MISFIT_BIN_PX` bins of distance
    past the edge of the bin's median residual, each bin weighted by its
    pixels, less what the noise leaves in such medians and
    :data:`MISFIT_NOISE_SIGMAS` times its spread, over ``|gain|``: the
    median pools hundreds of pixels from every vertex, so the noise
    averages away and a shape common to the vertices (a wrong law, a capped
    brightening, a PSF the model does not have) stays. ``edge_scatter_px``
    is the robust spread (1.4826 MAD) of each vertex's own edge shift along
    its normal, the residuals of its strip projected on the model's
    derivative along the normal, ``sum(g r) / sum(g^2)``: what the noise
    gives, ``edge_noise_px``, is ``residual_scale`` over ``sqrt(sum(g^2))``,
    the median over the vertices; relief or texture that moves the edge
    from vertex to vertex spreads it further. ``gain_scatter`` is the same
    for each vertex's own gain, fitted with its shift and background (a 3 x
    3 system per vertex), over ``|gain|``: an albedo that varies along the
    edge spreads it beyond ``gain_noise``. ``residual_scale`` is the
    residuals' robust scale (1.4826 MAD), as the pixels give it (the Tukey
    weights' scale is floored at ``SCALE_FLOOR`` of the gain; this one is
    not). All NaN for no pixels or a gain that is not positive."""
    k = pb.kernels
    gain = abs(float(params[2]))
    kk, ii, jj = _strips(pb, np.ascontiguousarray(pb.verts + np.asarray(pb.d0)), pb.normals,
                         pb.tau)  # (less the masked pixels)
    if ii.shape[0] == 0 or not gain > 0.0:
        return Misfit(math.nan, math.nan, math.nan, math.nan, math.nan, math.nan)
    pv, pu = ii.astype(np.float64), jj.astype(np.float64)
    tab = k.all_tables(pb.values, pb.shape, pb.o0, pb.h, pb.j0, pb.nb, float(params[4]))
    held = params.copy()
    held[7] = 0.0  # the wings, when any, are in the profile (_with_wings)
    r, jac = k.evaluate(np.ascontiguousarray(pb.image[ii, jj]), kk, pv, pu, pb.verts,
                        pb.normals, pb.curv, *tab[:6], pb.use_shape, tab[6], tab[7], *tab[:6],
                        False, tab[6], tab[7], held)
    r = np.asarray(r)
    n = pb.normals[kk]
    past = ((pv - pb.verts[kk, 0] - held[0]) * n[:, 0]
            + (pu - pb.verts[kk, 1] - held[1]) * n[:, 1])
    bins = np.round(past / MISFIT_BIN_PX).astype(np.int64)
    # each bin's median: its residuals sorted within it, the middle one (or
    # the mean of the middle two), as np.median gives
    rs = r[np.lexsort((r, bins))]
    bs = np.sort(bins, kind="stable")
    first = np.concatenate(([0], np.flatnonzero(np.diff(bs)) + 1))
    sizes = np.diff(np.append(first, bs.shape[0]))
    med = (rs[first + (sizes - 1) // 2] + rs[first + sizes // 2]) / 2.0
    count = sizes.astype(np.float64)
    # what the noise leaves in a bin's squared median: v = (1.2533 sigma)^2 / n
    # on average, with a spread of sqrt(2) v, sigma the residuals' robust scale
    # (which a shape inflates: the estimate is cautious); the shape is what
    # exceeds that by MISFIT_NOISE_SIGMAS of its spread
    scale = 1.4826 * float(np.median(np.abs(r)))
    v = (1.2533 * scale) ** 2 / count
    total = float(count.sum())
    excess = float(np.sum(count * (med**2 - v))) / total
    spread = math.sqrt(2.0 * float(np.sum((count * v) ** 2))) / total
    shape = math.sqrt(max(excess - MISFIT_NOISE_SIGMAS * spread, 0.0)) / gain
    # each vertex's edge shift: its residuals on the model's slope along the normal
    slope = np.asarray(jac)[:, 0] * n[:, 0] + np.asarray(jac)[:, 1] * n[:, 1]
    nv = pb.verts.shape[0]
    sgg = np.bincount(kk, slope * slope, minlength=nv)
    seen = sgg > 0.0
    if not seen.any():
        return Misfit(shape, math.nan, math.nan, math.nan, math.nan, scale)
    shift = np.bincount(kk, slope * r, minlength=nv)[seen] / sgg[seen]
    scatter = 1.4826 * float(np.median(np.abs(shift - np.median(shift))))
    noise = scale * float(np.median(1.0 / np.sqrt(sgg[seen])))
    gains, gains_noise = _gain_scatter(kk, nv, np.stack([slope, jac[:, 2], jac[:, 3]], axis=1),
                                       r, scale)
    return Misfit(shape, scatter, noise, gains / gain, gains_noise / gain, scale)


def _gain_scatter(kk: NDArray[np.int64], nv: int, cols: FloatArray, r: FloatArray,
                  scale: float) -> tuple[float, float]:
    """The robust spread (1.4826 MAD) of each vertex's own gain change, the
    residuals of its strip fitted on ``cols`` (the model's derivatives by
    the shift along its normal, the gain and the background: a 3 x 3 system
    per vertex), and the spread the noise explains (``scale`` times the
    root of the gain's diagonal of each inverse, the median over the
    vertices); NaN, NaN when fewer than :data:`MIN_VERTICES` vertices'
    systems are solvable."""
    def s(i: int, j: int) -> FloatArray:
        return np.bincount(kk, cols[:, i] * cols[:, j], minlength=nv).astype(np.float64,
                                                                             copy=False)

    a00, a01, a02, a11, a12, a22 = s(0, 0), s(0, 1), s(0, 2), s(1, 1), s(1, 2), s(2, 2)
    b0, b1, b2 = (np.bincount(kk, cols[:, i] * r, minlength=nv) for i in range(3))
    # the gain's row of each symmetric system's inverse: its cofactors over
    # the determinant (closed form: no batched LAPACK call per refinement)
    c10, c11, c12 = a02 * a12 - a01 * a22, a00 * a22 - a02 * a02, a01 * a02 - a00 * a12
    det = a00 * (a11 * a22 - a12 * a12) + a01 * c10 + a02 * (a01 * a12 - a11 * a02)
    scale3 = np.maximum(a00, 1e-300) * np.maximum(a11, 1e-300) * np.maximum(a22, 1e-300)
    solvable = np.abs(det) > 1e-9 * scale3
    if int(solvable.sum()) < MIN_VERTICES:
        return math.nan, math.nan
    d = det[solvable]
    dg = (c10[solvable] * b0[solvable] + c11[solvable] * b1[solvable]
          + c12[solvable] * b2[solvable]) / d
    spread = 1.4826 * float(np.median(np.abs(dg - np.median(dg))))
    return spread, scale * float(np.median(np.sqrt(np.maximum(c11[solvable] / d, 0.0))))


def _start(d0: tuple[float, float], sigma: float, wings: bool) -> FloatArray:
    """The start parameters (see ``dtalign._kernels.profile.N_PARAMS``): the
    offset ``d0``, the gain and background to be solved for, the sigma, and
    the wings' start when ``wings`` (else none)."""
    frac = WING_FRACTION_START if wings else 0.0
    kp = loop.profile_kernels
    return np.array([d0[0], d0[1], 0.0, 0.0, sigma, 0.0, 0.0, frac,
                     max(WING_SIGMA_START_PX, kp.MIN_WING_RATIO * sigma, kp.MIN_WING_SIGMA_PX)])


def _estimate_psf(pb: _Problem, params: FloatArray, fit_sigma: bool, wings: bool
                  ) -> tuple[FloatArray, int]:
    """The PSF estimated on a subset of the vertices with the shape free (a
    wrong law would bias it), then held: its sigma when ``fit_sigma`` (a
    single Gaussian first), then its wings when ``wings`` (from the single
    Gaussian's fit: started from a narrow core, a core and wings can mimic
    a wider Gaussian inside the strips, and do). Returns the start
    parameters of the full run and the iterations spent. With wings found,
    the full run starts as one with a given PSF does (its gain and
    background solved at the DT lock: a start from the stage's were slow to
    converge on a surface of the wrong law); with none, as it would without
    the wings' stage."""
    stride = max(1, pb.verts.shape[0] // SIGMA_VERTICES)
    idx = np.arange(0, pb.verts.shape[0], stride, dtype=np.int64)
    p_a = params
    iterations = 0
    if fit_sigma:
        p_a, it_a, _, _, _, _, _ = _run(pb, idx, params, True, SIGMA_TOLERANCE)
        p_a = np.array(p_a, dtype=np.float64)
        p_a[4] = max(float(p_a[4]), 0.0)
        iterations += int(it_a)
    out = np.array(p_a, dtype=np.float64)
    if wings:
        start = np.array(p_a, dtype=np.float64)
        start[7] = params[7]
        start[8] = max(float(params[8]), loop.profile_kernels.MIN_WING_RATIO * start[4])
        # a sigma of 0 is a stationary point of the model (the blur's change
        # is second order): the wings are then fitted with the sigma held
        p_b, it_b, _, _, _, _, _ = _run(pb, idx, start, fit_sigma and start[4] > 0.0,
                                        SIGMA_TOLERANCE, wings=True, fit_wings=True)
        iterations += int(it_b)
        if p_b[7] > MIN_WING_FRACTION:
            out = np.array(params, dtype=np.float64)
            out[4], out[7], out[8] = max(float(p_b[4]), 0.0), float(p_b[7]), float(p_b[8])
        else:  # none found: the full run starts as it would without the wings' stage
            out[7] = 0.0
    out[0], out[1] = pb.d0
    return out, iterations


def _with_wings(pb: _Problem, params: FloatArray) -> _Problem:
    """``pb`` with a profile whose model under the core Gaussian alone is the
    model under the core and the wings of ``params`` (itself when it has
    none): Gaussians compose, so the wing component ``f (P * G_w)`` is
    ``f (P * G_e) * G_core`` with ``e^2 = w^2 - core^2``; the profile
    becomes ``(1 - f) P + f (P * G_e)`` (the kernels' ``wing_mixed``), the
    second term read at the wing's extra curvature shift
    ``kappa (w^2 - core^2) / 2`` (the model reads each component at
    ``s - kappa (tau^2 + sigma^2 + 1/12) / 2``). ``P * G_e`` is linearly
    interpolated from the kernels' blurred table; it is at least
    ``MIN_WING_RATIO`` core sigmas wide, so the interpolation's error is
    far below the profile's own."""
    frac, sigma, sigma_w = float(params[7]), float(params[4]), float(params[8])
    if not frac > 0.0:
        return pb
    extra2 = sigma_w * sigma_w - sigma * sigma
    shift = np.ascontiguousarray((0.5 * extra2) * pb.curv)

    def mixed(rows: FloatArray) -> FloatArray:
        return np.asarray(pb.kernels.wing_mixed(rows, pb.o0, pb.h, frac, math.sqrt(extra2),
                                                shift))

    shape = mixed(pb.shape) if pb.use_shape else pb.shape
    return pb._replace(values=mixed(pb.values), shape=shape)


def _recentred(pb: _Problem, params: FloatArray) -> tuple[_Problem, FloatArray, Any]:
    """A terminator's offset fit from ``params`` (the sigma held): run again
    with the strips centred where it went while it lands more than
    :data:`TERMINATOR_CENTRED_PX` from their centre (the scan places it
    along the mean normal only; at high phase the DT lock is off across it
    too), at most :data:`TERMINATOR_RECENTRES` runs. Returns the last run's problem (its
    strips' centre ``d0``), its start parameters and its :func:`_run`
    output with the iterations of every run."""
    total = 0
    for _ in range(TERMINATOR_RECENTRES):
        out = _run(pb, None, params, False, TOLERANCE_PX)
        total += int(out[1])
        p, conv = out[0], bool(out[2])
        off = (float(p[0]), float(p[1]))
        if math.hypot(off[0] - pb.d0[0], off[1] - pb.d0[1]) <= TERMINATOR_CENTRED_PX or not conv:
            break
        pb = pb._replace(d0=off)
        params = _start(off, float(p[4]), False)
    return pb, params, (out[0], total, *out[2:])


def _terminator_fit(pb: _Problem, params: FloatArray, known: bool) -> tuple[_Problem, Any]:
    """A terminator's offset fit from ``params``: :func:`_recentred`, then,
    when the sigma is estimated (not ``known``), the last run again with
    the sigma free on every vertex (:data:`TERMINATOR_FREE_SIGMA`: the blur
    trades with a kink's position). A free run that stops at a sigma of 0
    without converging is held there, then run free once more from
    :data:`SIGMA_START_PX`, which is kept when it converges above 0
    (docs/profiles.rst, "A blur trapped at 0"). Returns the last run's
    problem and its :func:`_run` output with the iterations of every run."""
    pb, _, out = _recentred(pb, params)
    if not (TERMINATOR_FREE_SIGMA and not known and bool(out[2])):
        return pb, out
    iterations = int(out[1])
    out = _run(pb, None, np.array(out[0], dtype=np.float64), True, TOLERANCE_PX)
    iterations += int(out[1])
    if not bool(out[2]) and not float(out[0][4]) > 0.0:
        # it stopped at a sigma of 0, a stationary point of the model (the
        # blur's change is second order): held there
        out = _run(pb, None, np.array(out[0], dtype=np.float64), False, TOLERANCE_PX)
        iterations += int(out[1])
        # A step clamped to 0 can never leave it (the sigma's gradient is 0
        # there), whatever the cost at larger sigmas: run free once more from
        # the starting sigma, kept when it converges above 0
        start = np.array(out[0], dtype=np.float64)
        start[4] = SIGMA_START_PX
        again = _run(pb, None, start, True, TOLERANCE_PX)
        iterations += int(again[1])
        if bool(again[2]) and float(again[0][4]) > 0.0:
            out = again
    return pb, (out[0], iterations, *out[2:])


def _scan_start(pb: _Problem, sigma: float) -> tuple[float, float]:
    """A terminator's start: the offset along the polyline's mean normal,
    from :data:`SCAN_DARK_PX` behind the DT lock to :data:`SCAN_LIT_PX`
    ahead, whose strips' pixels correlate best with the profile model
    (gain and background free: the correlation; a strip wholly on the dark
    side correlates with nothing, one wholly on the ramp less than the kink
    does)."""
    k = pb.kernels
    nbar = pb.normals.sum(axis=0)
    norm = math.hypot(float(nbar[0]), float(nbar[1]))
    if not norm > 0.0:
        return pb.d0
    nbar = nbar / norm
    b, c, d, t0, ht = k.tables(pb.values, pb.o0, pb.h, pb.j0, pb.nb, sigma)
    ts = np.arange(-SCAN_DARK_PX, SCAN_LIT_PX + 0.5 * SCAN_STEP_PX, SCAN_STEP_PX)
    scores = np.full(ts.shape[0], -np.inf)
    for q, t in enumerate(ts):
        off = np.asarray(pb.d0) + t * nbar
        kk, ii, jj = _strips(pb, np.ascontiguousarray(pb.verts + off), pb.normals, pb.tau)
        if ii.shape[0] < 3:
            continue
        obs = np.ascontiguousarray(pb.image[ii, jj])
        r, _ = k.evaluate(obs, kk, ii.astype(np.float64), jj.astype(np.float64), pb.verts,
                          pb.normals, pb.curv, b, c, d, b, c, d, False, t0, ht,
                          b, c, d, b, c, d, False, t0, ht,
                          np.array([off[0], off[1], 1.0, 0.0, sigma, 0.0, 0.0, 0.0, 0.0]))
        model = obs - r
        sm, so = float(model.std()), float(obs.std())
        if sm > 0.0 and so > 0.0:
            scores[q] = float(((model - model.mean()) * (obs - obs.mean())).mean() / (sm * so))
    if not np.isfinite(scores).any():
        return pb.d0
    q = int(np.argmax(scores))
    t = float(ts[q])
    if 0 < q < ts.shape[0] - 1 and np.isfinite(scores[q - 1 : q + 2]).all():
        y0, y1, y2 = scores[q - 1], scores[q], scores[q + 1]
        den = y0 - 2.0 * y1 + y2
        if den < 0.0:
            t += 0.5 * SCAN_STEP_PX * float(y0 - y2) / float(den)
    return (pb.d0[0] + t * float(nbar[0]), pb.d0[1] + t * float(nbar[1]))


class _Problem(NamedTuple):
    """One refinement's fixed inputs, as the kernels take them."""

    image: FloatArray
    verts: FloatArray  #: the vertices at the DT-LM rotation
    normals: FloatArray
    curv: FloatArray
    values: FloatArray
    shape: FloatArray  #: the law-correction shape, (N, 0) without one
    use_shape: bool
    tau: FloatArray
    o0: float  #: the profile table's first offset
    h: float  #: its step
    j0: int  #: the table columns the strips reach: j0 .. j0 + nb - 1
    nb: int
    d0: tuple[float, float]  #: the DT-LM offset, the start
    kernels: Any
    fit_slope: bool = FIT_SLOPE  #: fit the background slope (:data:`FIT_SLOPE`; not a terminator's)
    mask: NDArray[np.bool_] | None = None  #: bad pixels, left out of the strips


def _strips(pb: _Problem, verts: FloatArray, normals: FloatArray, tau: FloatArray
            ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """The strips' pixels ``(vertex, row, column)`` of ``verts`` (the kernels'
    ``select_pixels``), less those on ``pb.mask``."""
    hgt, wid = pb.image.shape
    kk, ii, jj = pb.kernels.select_pixels(hgt, wid, verts, normals, tau, HALF_WIDTH_PX)
    if pb.mask is not None:
        keep = ~pb.mask[ii, jj]
        kk, ii, jj = (np.ascontiguousarray(a[keep]) for a in (kk, ii, jj))
    return kk, ii, jj


def _problem(image: FloatArray, profile: EdgeProfile, vertices_vu: ArrayLike,
             dt_offset_vu: tuple[float, float], rotation_rad: float,
             pivot_vu: tuple[float, float] | None, kernels: Any) -> _Problem:
    verts = np.ascontiguousarray(vertices_vu, dtype=np.float64)
    normals = np.ascontiguousarray(profile.normals_vu, dtype=np.float64)
    if rotation_rad != 0.0:
        verts = _rotated(verts, rotation_rad, pivot_vu)
        normals = _rotated(normals, rotation_rad, None)
    values = np.ascontiguousarray(profile.values)
    shape = (np.ascontiguousarray(profile.shape_values) if profile.shape_values is not None
             else np.zeros((values.shape[0], 0)))
    h = profile.step_px
    o0 = float(profile.offsets_px[0])
    reach = HALF_WIDTH_PX + TABLE_MARGIN_PX
    j0 = max(0, int(math.floor((-reach - o0) / h)))
    j1 = min(values.shape[1] - 1, int(math.ceil((reach - o0) / h)))
    return _Problem(
        image=image, verts=verts, normals=normals,
        curv=np.ascontiguousarray(profile.curvature_px), values=values, shape=shape,
        use_shape=profile.shape_values is not None, tau=_tau_max(verts), o0=o0, h=h, j0=j0,
        nb=j1 - j0 + 1, d0=(float(dt_offset_vu[0]), float(dt_offset_vu[1])), kernels=kernels,
        fit_slope=FIT_SLOPE and profile.edge != "terminator",
    )


def _run(pb: _Problem, idx: NDArray[np.int64] | None, params: FloatArray, fit_sigma: bool,
         tolerance: float, *, wings: bool = False, fit_wings: bool = False) -> Any:
    """The kernels' refinement over the vertices ``idx`` (all when None) from
    ``params``, with the PSF's wings when ``wings`` (fitted when
    ``fit_wings``, else held): ``(params, iterations, converged, inverse,
    scale, _, n_pixels)``."""
    k = pb.kernels
    arrays: tuple[FloatArray, ...] = (pb.verts, pb.normals, pb.curv, pb.values, pb.shape, pb.tau)
    if idx is not None:
        arrays = tuple(np.ascontiguousarray(a[idx]) for a in arrays)
    v, nrm, cv, val, shp, tm = arrays
    kk, ii, jj = _strips(pb, np.ascontiguousarray(v + np.asarray(pb.d0)), nrm, tm)
    obs = np.ascontiguousarray(pb.image[ii, jj])
    pv = ii.astype(np.float64)
    pu = jj.astype(np.float64)
    params = params.copy()
    if not wings:
        params[7] = 0.0
    active = ([0, 1, 2, 3] + ([4] if fit_sigma else []) + ([5] if pb.use_shape else [])
              + ([6] if pb.fit_slope else [])
              + ([7] + ([8] if FIT_WING_SIGMA else []) if wings and fit_wings else []))
    npx = obs.shape[0]
    if 0 < npx <= len(active):
        raise _Unusable(f"too few pixels in the strips ({npx} for {len(active)} parameters)", npx)
    if params[2] == 0.0 and npx > 0:  # the linear gain and background at the start
        b, c, d, t0, ht = k.tables(val, pb.o0, pb.h, pb.j0, pb.nb, params[4])
        r, _ = k.evaluate(obs, kk, pv, pu, v, nrm, cv, b, c, d, b, c, d, False, t0, ht,
                          b, c, d, b, c, d, False, t0, ht,
                          np.array([pb.d0[0], pb.d0[1], 1.0, 0.0, params[4], 0.0, 0.0, 0.0, 0.0]))
        model = obs - r
        bad = int(np.count_nonzero(~np.isfinite(model)))
        if bad:
            raise _Unusable(f"the profile's model is not finite at {bad} of {npx} pixels", npx)
        if not np.ptp(model) > 0.0:
            raise _Unusable("the profile's model has no contrast across the strips' pixels", npx)
        a = np.stack([model, np.ones_like(model)], axis=1)
        sol = np.linalg.lstsq(a, obs, rcond=None)[0]
        params[2], params[3] = float(sol[0]), float(sol[1])
    out = k.refine(obs, kk, pv, pu, v, nrm, cv, val, shp, pb.o0, pb.h, pb.j0, pb.nb, params,
                   np.asarray(active, dtype=np.int64), bool(wings), MAX_ITERATIONS, tolerance,
                   TUKEY_C)
    if npx > 0 and not np.isfinite(out[0]).all():
        raise _Unusable("the Gauss-Newton reached a value that is not finite", npx)
    return (*out, npx)


def _rejection(n_pixels: int, converged: bool, iterations: int, walk: float, gain: float,
               cov: FloatArray, start: str = "the DT lock") -> str:
    """Why a refinement is discarded ("" when it is accepted); ``walk`` is from
    ``start``, ``cov`` the offset's covariance."""
    if n_pixels == 0:
        return "no pixels in the strips along the normals (is the polyline in the image?)"
    if not np.isfinite(cov).all():
        return "its information matrix is singular: the strips' pixels do not fix the offset"
    if not converged:
        return f"did not converge in {iterations} Gauss-Newton iterations"
    if not walk <= MAX_WALK_PX:
        return f"walked {walk:.3g} px from {start} (more than {MAX_WALK_PX:g} px)"
    if not gain > 0.0:
        return f"fitted a non-positive gain ({gain:.3g}): the profile does not match the image"
    return ""


def profile_samples(
    image: ArrayLike, profile: EdgeProfile, vertices_vu: ArrayLike, refinement: ProfileRefinement,
    indices: Any, *, n_model: int = 200,
) -> list[dict[str, FloatArray]]:
    """The image pixels and the fitted model across some vertices (for plots).

    Parameters
    ----------
    image : array_like, shape (H, W)
    profile : EdgeProfile
    vertices_vu : array_like, shape (N, 2)
        The model vertices (before the pose; the rotation is not applied).
    refinement : ProfileRefinement
        The refinement whose parameters draw the model.
    indices : sequence of int
        The vertices.
    n_model : int, optional
        Samples of the model curve across the strip.

    Returns
    -------
    list of dict
        Per vertex: ``s`` (each strip pixel's distance past the edge at the
        refined pose, along the normal, px), ``value`` (its image value),
        ``model_s`` and ``model`` (the fitted model on the normal through
        the vertex), ``dt_shift`` (where the DT-LM pose puts the edge on
        that axis, px).
    """
    kernels = loop.profile_kernels

    img = check.check_image(image)
    verts = np.ascontiguousarray(vertices_vu, dtype=np.float64)
    r = refinement
    params = np.array([r.offset_vu[0], r.offset_vu[1], r.gain, r.background, r.psf_sigma_px,
                       r.shape_amplitude, r.background_slope, r.wing_fraction,
                       r.wing_sigma_px if r.wing_fraction > 0.0 else 0.0])
    wings = r.wing_fraction > 0.0
    h = profile.step_px
    o0 = float(profile.offsets_px[0])
    reach = HALF_WIDTH_PX + TABLE_MARGIN_PX
    j0 = max(0, int(math.floor((-reach - o0) / h)))
    j1 = min(profile.values.shape[1] - 1, int(math.ceil((reach - o0) / h)))
    out = []
    tau = _tau_max(verts)
    for k in (int(i) for i in indices):
        sel = np.array([k])
        v = np.ascontiguousarray(verts[sel])
        nrm = np.ascontiguousarray(profile.normals_vu[sel])
        cv = np.ascontiguousarray(profile.curvature_px[sel])
        val = np.ascontiguousarray(profile.values[sel])
        shp = (np.ascontiguousarray(profile.shape_values[sel]) if profile.shape_values is not None
               else np.zeros((1, 0)))
        tab = kernels.all_tables(val, shp, o0, h, j0, j1 - j0 + 1, r.psf_sigma_px)
        wtab = (kernels.all_tables(val, shp, o0, h, j0, j1 - j0 + 1, float(params[8]))
                if wings else tab)
        kk, ii, jj = kernels.select_pixels(img.shape[0], img.shape[1],
                                           np.ascontiguousarray(v + np.asarray(r.offset_vu)),
                                           nrm, np.ascontiguousarray(tau[sel]), HALF_WIDTH_PX)
        pv, pu = ii.astype(np.float64), jj.astype(np.float64)
        obs = np.ascontiguousarray(img[ii, jj])
        use_shape = shp.shape[1] > 0
        rr, _ = kernels.evaluate(obs, kk, pv, pu, v, nrm, cv, *tab[:6], use_shape, tab[6], tab[7],
                                 *wtab[:6], wings, wtab[6], wtab[7], params)
        s_px = (pv - v[0, 0] - r.offset_vu[0]) * nrm[0, 0] + (pu - v[0, 1] - r.offset_vu[1]) * nrm[0, 1]
        ms = np.linspace(-HALF_WIDTH_PX, HALF_WIDTH_PX, n_model)
        mv = v[0, 0] + r.offset_vu[0] + ms * nrm[0, 0]
        mu = v[0, 1] + r.offset_vu[1] + ms * nrm[0, 1]
        zeros = np.zeros(n_model)
        model, _ = kernels.evaluate(zeros, np.zeros(n_model, dtype=np.int64), mv, mu, v, nrm, cv,
                                    *tab[:6], use_shape, tab[6], tab[7], *wtab[:6], wings,
                                    wtab[6], wtab[7], params)
        dt_shift = float((np.asarray(r.dt_offset_vu) - np.asarray(r.offset_vu)) @ nrm[0])
        out.append({"s": s_px, "value": obs, "model_s": ms, "model": -model,
                    "residual": rr, "dt_shift": np.asarray(dt_shift)})
    return out
