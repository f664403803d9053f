"""Pictures of a fit: the model on the image, and the residuals.

matplotlib is an optional dependency (``pip install matplotlib``, or the
``plot`` extra: ``pip install ".[plot]"`` in a clone). It is imported only
when a plotting function is called, and figures are built with the
object-oriented API on an Agg canvas, so plotting works on a headless
machine and never changes the caller's pyplot backend or state. Pass
``ax=`` to draw into an axes of your own figure instead.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from .api import checks as check
from .api.constants import POLARITY_PENALTY_RESIDUAL

if TYPE_CHECKING:
    from .pipeline.fit import PolylineFit

__all__ = ["plot_fit", "plot_profile_fit", "plot_residual_histogram"]

_INSTALL_HINT = "plotting needs matplotlib: pip install matplotlib"


def _figure(figsize: tuple[float, float]) -> Any:
    """A new Figure on an Agg canvas (no pyplot, no global state)."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise ImportError(_INSTALL_HINT) from None
    fig = Figure(figsize=figsize, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Any, path: str | Path | None, dpi: int) -> None:
    if path is not None:
        fig.savefig(Path(path), dpi=dpi)


def _nice_scale(target: float) -> float:
    """The largest 1-2-5 number not above ``target`` (at least 1)."""
    if not math.isfinite(target) or target <= 1.0:
        return 1.0
    exp = math.floor(math.log10(target))
    best = 10.0**exp
    for m in (2.0, 5.0):
        if m * 10**exp <= target:
            best = m * 10**exp
    return best


def _ellipse_points(cov: np.ndarray, scale: float, n: int = 200) -> np.ndarray:
    """Points ``(v, u)`` of the scaled one-sigma ellipse of a 2 x 2 covariance."""
    values, vectors = np.linalg.eigh(0.5 * (cov + cov.T))
    radii = scale * np.sqrt(np.maximum(values, 0.0))
    t = np.linspace(0.0, 2.0 * np.pi, n)
    circle = np.stack([radii[0] * np.cos(t), radii[1] * np.sin(t)])
    return (vectors @ circle).T


def plot_fit(
    image: ArrayLike,
    vertices_vu: ArrayLike,
    fit: PolylineFit,
    path: str | Path | None = None,
    *,
    ax: Any = None,
    title: str | None = None,
    margin_px: float = 20.0,
    ellipse_scale: float | None = None,
    zoom_vu: Sequence[tuple[float, float]] | None = None,
    zoom_half_px: float = 20.0,
    figsize: tuple[float, float] = (8.0, 7.0),
    dpi: int = 110,
) -> Any:
    """Draw a fit: image crop, model at the initial and fitted pose, residuals.

    The image is cropped to the model at both poses plus a margin and
    shown with a 1-99.5 percentile stretch. The model at its initial pose
    (the vertices as given) is drawn as small cyan dots; at the fitted pose
    each vertex is coloured by its DT residual. Vertices the Tukey biweight
    rejected (weight 0 but polarity accepted) are circled in orange, those
    the polarity test rejected (residual ``1e6``) are marked with red
    crosses. The one-sigma covariance ellipse of the offset is drawn at the
    fitted centroid, magnified (the factor is in the legend) because a
    sub-pixel ellipse would be invisible; when the geometry leaves a
    direction unobservable, that direction is drawn as a dotted line.

    Parameters
    ----------
    image : array_like, shape (H, W)
        The image the polyline was fitted to.
    vertices_vu : array_like, shape (N, 2)
        The model vertices as passed to the fit.
    fit : PolylineFit
        The result of :func:`dtalign.fit_polyline`.
    path : str or path-like, optional
        Write the figure there (format from the suffix, e.g. ``.png``).
    ax : matplotlib.axes.Axes, optional
        Draw into this axes (and its figure's colour bar) instead of a new
        figure; ``figsize`` is then ignored and ``zoom_vu`` must be None
        (the zoom panels need a figure of their own).
    title : str, optional
        Axes title; a summary of the fit when None.
    margin_px : float, optional
        Margin around the model in the crop.
    ellipse_scale : float, optional
        Magnification of the covariance ellipse; chosen automatically
        (a 1-2-5 number making it about a tenth of the crop) when None.
    zoom_vu : sequence of (v, u), optional
        Add a zoomed panel (``2 * zoom_half_px`` wide) around each point,
        framed in yellow on the main view: on a full frame the pixel-level
        agreement is otherwise invisible.
    zoom_half_px : float, optional
        Half-size of each zoom panel, pixels.
    figsize, dpi
        Figure size in inches and resolution when saving.

    Returns
    -------
    matplotlib.figure.Figure
        The new figure, or ``ax``'s figure.

    Raises
    ------
    ImportError
        If matplotlib is not installed (the message says what to install).
    ValueError
        On a malformed image or vertices, or ``ax`` with ``zoom_vu``.
    """
    img = np.asarray(image, dtype=np.float64)
    if img.ndim != 2 or img.size == 0:
        raise ValueError(f"image must be a non-empty 2-D array, got shape {img.shape}")
    verts = check.vertices(vertices_vu, "vertices_vu", allow_empty=False)
    residuals = np.asarray(fit.lm.residuals_px)
    if residuals.shape[0] != verts.shape[0]:
        raise ValueError(
            f"vertices_vu has {verts.shape[0]} vertices but the fit has {residuals.shape[0]}"
        )
    fitted = fit.transform(verts)
    v0, v1, u0, u1 = _crop_box(img.shape, np.vstack([verts, fitted]), margin_px)
    zooms = [check.pair(z, "zoom_vu") for z in (zoom_vu or ())]
    fig, ax, zoom_axes = _fit_axes(ax, len(zooms), figsize)
    layers = _FitLayers.of(img, img[v0:v1, u0:u1], verts, fitted, residuals, fit)
    sc = layers.draw(ax, 1.0)
    fig.colorbar(
        sc, ax=[ax, *zoom_axes], shrink=0.8, extend="max",
        label="DT residual at the fitted pose (px)",
    )
    _draw_covariance(ax, fit, fitted.mean(axis=0), (v1 - v0, u1 - u0), ellipse_scale)
    ax.set_xlim(u0 - 0.5, u1 - 0.5)
    ax.set_ylim(v1 - 0.5, v0 - 0.5)
    ax.set_xlabel("u (column, px)")
    ax.set_ylabel("v (row, px)")
    ax.legend(loc="upper right", fontsize=8, framealpha=0.8)
    ax.set_title(title if title is not None else _summary(fit), fontsize=9)
    for zax, (zv, zu) in zip(zoom_axes, zooms, strict=True):
        layers.draw(zax, 6.0)
        zax.set_xlim(zu - zoom_half_px, zu + zoom_half_px)
        zax.set_ylim(zv + zoom_half_px, zv - zoom_half_px)
        zax.set_title(f"zoom at (v, u) = ({zv:.0f}, {zu:.0f})", fontsize=8)
        zax.tick_params(labelsize=7)
        ax.add_patch(_rectangle(zu - zoom_half_px, zv - zoom_half_px, 2 * zoom_half_px))
    _save(fig, path, dpi)
    return fig


def _crop_box(shape: tuple[int, ...], points: np.ndarray, margin_px: float
              ) -> tuple[int, int, int, int]:
    """``(v0, v1, u0, u1)``: the points plus a margin, within the image (all of it if none are)."""
    h, w = shape
    v0 = int(max(math.floor(points[:, 0].min() - margin_px), 0))
    v1 = int(min(math.ceil(points[:, 0].max() + margin_px) + 1, h))
    u0 = int(max(math.floor(points[:, 1].min() - margin_px), 0))
    u1 = int(min(math.ceil(points[:, 1].max() + margin_px) + 1, w))
    if v1 <= v0 or u1 <= u0:  # the model is entirely outside the image
        v0, v1, u0, u1 = 0, h, 0, w
    return v0, v1, u0, u1


def _fit_axes(ax: Any, n_zooms: int, figsize: tuple[float, float]) -> tuple[Any, Any, list[Any]]:
    """The figure, the main axes and a zoom panel's axes for each zoom point."""
    if ax is not None:
        if n_zooms:
            raise ValueError("zoom_vu needs a figure of its own: pass ax=None")
        return ax.figure, ax, []
    if n_zooms:
        fig = _figure((figsize[0] * 1.45, figsize[1]))
        grid = fig.add_gridspec(n_zooms, 2, width_ratios=(2.2, 1.0))
        return (fig, fig.add_subplot(grid[:, 0]),
                [fig.add_subplot(grid[i, 1]) for i in range(n_zooms)])
    fig = _figure(figsize)
    return fig, fig.add_subplot(1, 1, 1), []


@dataclass(frozen=True)
class _FitLayers:
    """What :func:`plot_fit` draws on its main view and again on each zoom panel."""

    img: np.ndarray
    lo: float  # the grey stretch: the crop's 1 and 99.5 percentiles
    hi: float
    verts: np.ndarray  # the model at its initial pose
    fitted: np.ndarray  # ... and at the fitted pose
    residuals: np.ndarray
    polarity: np.ndarray  # the vertices the polarity test rejected
    tukey: np.ndarray  # ... and those the Tukey biweight rejected
    vmax: float  # top of the residuals' colour scale
    size: float  # marker size, smaller for more vertices

    @classmethod
    def of(cls, img: np.ndarray, crop: np.ndarray, verts: np.ndarray, fitted: np.ndarray,
           residuals: np.ndarray, fit: Any) -> _FitLayers:
        lo, hi = (float(x) for x in np.percentile(crop, [1.0, 99.5]))
        weighted = residuals[np.asarray(fit.lm.weights) > 0.0]
        return cls(
            img, lo, hi if hi > lo else lo + 1.0, verts, fitted, residuals,
            fit.polarity_rejected, fit.tukey_rejected,
            max(float(np.percentile(weighted, 99.0)) if weighted.size else 1.0, 1e-3),
            float(np.clip(3000.0 / max(verts.shape[0], 1), 2.0, 16.0)),
        )

    def draw(self, axis: Any, scale: float) -> Any:
        """Image, model at both poses, rejected vertices; returns the residuals' scatter."""
        h, w = self.img.shape
        fitted, size, ok = self.fitted, self.size, ~self.polarity
        axis.imshow(
            self.img, cmap="gray", vmin=self.lo, vmax=self.hi, interpolation="nearest",
            extent=(-0.5, w - 0.5, h - 0.5, -0.5),
        )
        axis.scatter(
            self.verts[:, 1], self.verts[:, 0], s=size * 0.5 * scale, c="cyan", lw=0,
            label="model, initial pose",
        )
        sc = axis.scatter(
            fitted[ok, 1], fitted[ok, 0], s=size * scale, c=self.residuals[ok], cmap="plasma",
            vmin=0.0, vmax=self.vmax, lw=0, label="model, fitted pose",
        )
        if self.tukey.any():
            axis.scatter(
                fitted[self.tukey, 1], fitted[self.tukey, 0], s=size * 4 * scale,
                facecolors="none", edgecolors="orange", lw=0.8,
                label=f"Tukey-rejected ({int(self.tukey.sum())})",
            )
        if self.polarity.any():
            axis.scatter(
                fitted[self.polarity, 1], fitted[self.polarity, 0], s=size * 3 * scale, c="red",
                marker="x", lw=0.8, label=f"polarity-rejected ({int(self.polarity.sum())})",
            )
        return sc


def _rectangle(u: float, v: float, size: float) -> Any:
    from matplotlib.patches import Rectangle

    return Rectangle((u, v), size, size, fill=False, edgecolor="yellow", lw=1.0)


def _summary(fit: Any) -> str:
    dv, du = fit.offset_vu
    sv, su = fit.sigma_vu
    # the status leads: a picture of a failed fit must not read as a result
    status = getattr(fit, "status", None)
    reasons = tuple(getattr(fit, "reasons", ()))
    text = ""
    if status is not None:
        label = str(status).upper() if str(status) != "ok" else "ok"
        text = f"status {label}" + (f" ({', '.join(map(str, reasons))})" if reasons else "") + "\n"
    if str(status) == "failed":
        text += f"no offset measured (the LM stopped at ({dv:.2f}, {du:.2f}))"
    else:
        text += f"offset (dv, du) = ({dv:.3f} ± {sv:.3f}, {du:.3f} ± {su:.3f}) px"
    if fit.fit_rotation:
        text += f", rotation {fit.rotation_rad:.5f} rad"
    text += f"\ncoarse seed {fit.coarse_offset_vu}, rms {fit.lm.rms_px:.3f} px, "
    text += f"inliers {fit.lm.inlier_count}/{len(fit.lm.residuals_px)}"
    rank = fit.observable_rank
    if rank < (fit.n_params):
        text += f", observable rank {rank}"
    if fit.at_window_edge:
        text += ", AT SEARCH-WINDOW EDGE"
    return text


def _draw_covariance(
    ax: Any, fit: Any, centre: np.ndarray, crop_shape: tuple[int, int], scale: float | None
) -> None:
    cov = np.asarray(fit.covariance)[:2, :2]
    if not np.isfinite(cov).all():
        return
    values = np.linalg.eigvalsh(cov)
    major = math.sqrt(max(float(values.max()), 0.0))
    target = 0.1 * min(crop_shape)
    if scale is None:
        scale = _nice_scale(target / major) if major > 0 else 1.0
    pts = _ellipse_points(cov, scale) + centre
    ax.plot(pts[:, 1], pts[:, 0], color="lime", lw=1.2, label=f"1σ covariance ellipse × {scale:g}")
    for e in fit.unobservable_directions:
        if e.shape[0] < 2 or np.hypot(e[0], e[1]) < 1e-6:
            continue
        d = e[:2] / np.hypot(e[0], e[1]) * 0.25 * max(crop_shape)
        ax.plot(
            [centre[1] - d[1], centre[1] + d[1]],
            [centre[0] - d[0], centre[0] + d[0]],
            color="lime",
            ls=":",
            lw=1.2,
            label="unobservable direction",
        )


def plot_residual_histogram(
    fit: PolylineFit,
    path: str | Path | None = None,
    *,
    ax: Any = None,
    bins: int = 40,
    sigma_px: float | None = None,
    figsize: tuple[float, float] = (6.0, 4.0),
    dpi: int = 110,
) -> Any:
    """Histogram of the DT residuals at the fitted pose.

    Polarity-rejected vertices (residual ``1e6``) are counted in the title
    but not binned. Weighted inliers and Tukey-rejected vertices are
    stacked in two colours. With ``sigma_px`` (the vertices' common prior
    sigma) the Tukey cutoff ``tukey_c * sigma_px`` is drawn.

    Parameters
    ----------
    fit : PolylineFit
        The result of :func:`dtalign.fit_polyline`.
    path : str or path-like, optional
        Write the figure there.
    ax : matplotlib.axes.Axes, optional
        Draw into this axes instead of a new figure (``figsize`` ignored).
    bins : int, optional
        Number of histogram bins.
    sigma_px : float, optional
        The prior sigma, to draw the cutoff.
    figsize, dpi
        Figure size in inches and resolution when saving.

    Returns
    -------
    matplotlib.figure.Figure
    """
    residuals = np.asarray(fit.lm.residuals_px)
    polarity = residuals == POLARITY_PENALTY_RESIDUAL
    tukey = fit.tukey_rejected
    inlier = ~polarity & ~tukey
    if ax is None:
        fig = _figure(figsize)
        ax = fig.add_subplot(1, 1, 1)
    else:
        fig = ax.figure
    data = [residuals[inlier], residuals[tukey]]
    finite = np.concatenate(data)
    hi = float(finite.max()) if finite.size else 1.0
    ax.hist(
        data,
        bins=bins,
        range=(0.0, max(hi, 1e-3)),
        stacked=True,
        color=["tab:blue", "orange"],
        label=[f"weighted ({int(inlier.sum())})", f"Tukey-rejected ({int(tukey.sum())})"],
    )
    if sigma_px is not None:
        cut = fit.tukey_c * float(sigma_px)
        ax.axvline(cut, color="k", ls="--", lw=1, label=f"Tukey cutoff {cut:.2f} px")
    ax.set_xlabel("DT residual at the fitted pose (px)")
    ax.set_ylabel("vertices")
    ax.set_title(
        f"rms {fit.lm.rms_px:.3f} px (weighted), {int(polarity.sum())} polarity-rejected not shown",
        fontsize=9,
    )
    ax.legend(fontsize=8)
    _save(fig, path, dpi)
    return fig


def plot_profile_fit(
    fit: Any,
    image: ArrayLike,
    edge_profile: Any,
    path: str | Path | None = None,
    *,
    n_normals: int = 4,
    figsize: tuple[float, float] | None = None,
    dpi: int = 110,
) -> Any:
    """The profile refinement along a few normals: the image's pixels against the model.

    For ``n_normals`` vertices spread along the polyline (among those with
    the most contrast), each panel shows the pixels of the vertex's strip
    against their distance past the edge at the refined pose, the fitted
    model on the normal through the vertex, the geometric edge (0) and
    where the DT-LM pose put it.

    Parameters
    ----------
    fit : PolylineFit
        A fit made with ``edge_profile`` (its :attr:`~dtalign.pipeline.PolylineFit.profile`
        is set).
    image : array_like, shape (H, W)
        The image fitted.
    edge_profile : EdgeProfile
        The profile the fit used.
    path : str or path-like, optional
        Write the figure there.
    n_normals : int, optional
        Panels, >= 1.
    figsize : tuple of float, optional
        Figure size in inches (default: 3 inches per panel).
    dpi : int, optional
        Resolution when saving.

    Returns
    -------
    matplotlib.figure.Figure

    Raises
    ------
    ValueError
        If the fit has no profile refinement, or ``n_normals < 1``.
    """
    from .pipeline.profile_fit import profile_samples

    if getattr(fit, "profile", None) is None:
        raise ValueError("fit has no profile refinement: fit it with edge_profile=...")
    n = check.count(n_normals, "n_normals")
    if n < 1:
        raise ValueError("n_normals must be >= 1")
    values = np.asarray(edge_profile.values)
    contrast = np.ptp(values, axis=1)
    order = np.flatnonzero(contrast >= 0.5 * contrast.max()) if contrast.max() > 0 else np.arange(
        values.shape[0])
    picks = order[np.linspace(0, order.size - 1, min(n, order.size)).round().astype(int)]
    samples = profile_samples(image, edge_profile, fit.vertices_vu, fit.profile, picks)
    fig = _figure(figsize or (3.0 * len(picks), 3.2))
    for i, (k, smp) in enumerate(zip(picks, samples, strict=True)):
        ax = fig.add_subplot(1, len(picks), i + 1)
        ax.plot(smp["s"], smp["value"], ".", ms=4, color="tab:blue", label="pixels")
        ax.plot(smp["model_s"], smp["model"], "-", color="tab:orange", label="model")
        ax.axvline(0.0, color="k", lw=1, label="geometric edge")
        ax.axvline(float(smp["dt_shift"]), color="tab:red", lw=1, ls="--", label="DT-LM edge")
        ax.set_title(f"vertex {int(k)}", fontsize=9)
        ax.set_xlabel("px past the edge, along the normal", fontsize=8)
        if i == 0:
            ax.set_ylabel("image value")
            ax.legend(fontsize=7)
    p = fit.profile
    fig.suptitle(
        f"profile fit {'accepted' if p.accepted else 'discarded'}: offset "
        f"({p.offset_vu[0]:.3f}, {p.offset_vu[1]:.3f}), DT-LM ({p.dt_offset_vu[0]:.3f}, "
        f"{p.dt_offset_vu[1]:.3f}), PSF sigma {p.psf_sigma_px:.2f} px", fontsize=9)
    _save(fig, path, dpi)
    return fig
