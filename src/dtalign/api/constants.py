"""Module-level defaults of the fitter, with the reason each has its value.

Every value here is part of the drop-in contract (:ref:`contract-surface`): callers
and their tests read them by name, so they are re-exported unchanged from
:mod:`dtalign`.
"""

from __future__ import annotations

#: Holland-Welsch biweight cutoff in sigma units. 4.685 gives ~95 %
#: asymptotic efficiency on Gaussian residuals while still dropping
#: vertices more than ~4.7 sigma from any edge.
DEFAULT_TUKEY_C: float = 4.685

#: Initial Levenberg-Marquardt damping. Small enough that a well-posed
#: first step is almost Gauss-Newton; halved on accept, doubled on reject.
DEFAULT_LM_DAMPING: float = 1.0e-3

#: Safety net on LM iterations: a clean limb converges in 4-8, and a flat
#: DT plateau exits through the damping bound long before 30.
DEFAULT_LM_MAX_ITERATIONS: int = 30

#: Step norm (pixel-equivalent, rotation scaled by the pivot distance)
#: below which the fit is converged: far below the DT's own quantisation.
DEFAULT_LM_STEP_TOLERANCE: float = 1.0e-3

#: Relative eigenvalue cutoff of the pseudoinverse. Loose enough to fold
#: floating-point noise of an unobservable direction into the null space,
#: tight enough to keep genuine 2-D / 3-D constraints.
DEFAULT_PINVH_RCOND: float = 1.0e-9

#: Half-width of the profile sampled along each normal by the ridge polish:
#: the DT-LM pose is within a pixel or two of the gradient peak.
DEFAULT_RIDGE_HALF_WIDTH_PX: float = 3.0

#: Profile sample spacing; half a pixel resolves the peak for the parabola.
DEFAULT_RIDGE_SAMPLE_STEP_PX: float = 0.5

#: Gauss-Newton iterations of the ridge polish (it starts next to the peak).
DEFAULT_RIDGE_MAX_ITERATIONS: int = 10

#: The ridge result is discarded if it walks farther than this from the
#: DT-LM pose: it is a polish, not a second search.
DEFAULT_RIDGE_MAX_TOTAL_DISPLACEMENT_PX: float = 1.5

#: Gaussian pre-smoothing of the Sobel gradient, in pixels: suppresses
#: pixel noise while keeping a limb's transition about two pixels wide.
DEFAULT_IMAGE_GRADIENT_SIGMA_PX: float = 1.2

#: Edge threshold in units of the image noise sigma: a 4-sigma gradient is
#: rare in pure noise at 1024 x 1024.
DEFAULT_EDGE_THRESHOLD_K_SIGMA: float = 4.0

#: Truncation of the distance transform: beyond the largest pointing error
#: the exact distance carries no information, and the cap bounds the work.
DEFAULT_DT_HALF_WIDTH_PX: float = 64.0

#: Smallest fraction of a polyline's support that a coarse shift must keep
#: inside the image to be a candidate (:ref:`contract-coarse-scored`): a shift that
#: pushes most of the model off the frame would otherwise win on the few
#: pixels it keeps on an edge.
DEFAULT_COARSE_MIN_SUPPORT_FRACTION: float = 0.5

#: Residual given to polarity-rejected vertices: the Tukey biweight zeroes
#: any such vertex on the first reweighting. Today's techniques import it
#: as ``_INFINITY_DT_PENALTY_PX`` (:ref:`contract-today`).
#: The pipeline's coarse-search margin when a call gives none, px per axis:
#: wide enough for the pointing errors the navigation frames show (the
#: disc demo's offset is ~9 px), small enough that a 1024 x 1024 frame's
#: search stays a small part of the fit (``FitOptions.search_window_vu``,
#: the command line's ``--window``).
DEFAULT_SEARCH_WINDOW_VU: tuple[int, int] = (30, 30)

POLARITY_PENALTY_RESIDUAL: float = 1.0e6
_INFINITY_DT_PENALTY_PX: float = POLARITY_PENALTY_RESIDUAL

#: Central-difference half-step of the translation Jacobian, pixels.
JACOBIAN_TRANSLATION_EPS_PX: float = 0.25

#: Central-difference half-step of the rotation Jacobian, radians.
JACOBIAN_ROTATION_EPS_RAD: float = 1.0e-3

#: Damping bounds: hitting the upper one means the trust region collapsed.
LM_DAMPING_MIN: float = 1.0e-12
LM_DAMPING_MAX: float = 1.0e6

#: A ridge profile curvature must be below minus this to be a peak.
RIDGE_CURVATURE_EPS: float = 1.0e-12

#: Floor of the noise sigma used for the edge threshold, so a noiseless
#: image still has a strictly positive threshold.
NOISE_SIGMA_FLOOR: float = 1.0e-6
