"""PSFs from GalSim, applied to an oversampled render, then the detector.

The optic is Cassini-NAC-like: focal length 2.0 m, aperture 0.19 m, 12 um
pixels (6.0 urad), so at 0.65 um ``lambda / D`` = 3.42 urad = 0.57 px.
The central obscuration, 0.36 of the aperture's diameter, is an assumed
value typical of a Ritchey-Chretien telescope (not a published NAC figure).
The PSF kinds:

``none``
    no blur (the pixel's box only, which the render already integrates);
``gaussian``
    a Gaussian of ``sigma`` px: the navigator's model;
``nac``
    the obscured Airy convolved with Gaussian jitter of ``sigma`` px: a
    diffraction core with wings falling as ``r^-3``;
``nac_aniso``
    the same with the jitter sheared (``g1``, ``g2``): an anisotropic core;
``nac_smear``
    the Airy, jitter and a line smear of ``smear_px`` at ``smear_deg``.

GalSim draws the PSF on the oversampled grid with ``method="no_pixel"``
(the render's film pixels already integrate their area; the binning then
completes the output pixel's box), on an odd stamp centred on a pixel, of
``2 * STAMP_HALF_PX`` output pixels, normalised to unit sum.
"""

from __future__ import annotations

import numpy as np

NAC_LAM_OVER_DIAM_PX = 0.65e-6 / 0.19 / (12e-6 / 2.0)
NAC_OBSCURATION = 0.36
STAMP_HALF_PX = 24


def psf_object(kind: str, sigma: float = 0.0, g1: float = 0.0, g2: float = 0.0,
               smear_px: float = 0.0, smear_deg: float = 0.0):
    """The GalSim profile of a PSF kind (lengths in output pixels); None for ``none``."""
    import galsim

    if kind == "none":
        return None
    jitter = galsim.Gaussian(sigma=sigma)
    if kind == "gaussian":
        return jitter
    airy = galsim.Airy(lam_over_diam=NAC_LAM_OVER_DIAM_PX, obscuration=NAC_OBSCURATION)
    if kind == "nac":
        return galsim.Convolve(airy, jitter)
    if kind == "nac_aniso":
        return galsim.Convolve(airy, jitter.shear(g1=g1, g2=g2))
    if kind == "nac_smear":
        line = galsim.Box(width=smear_px, height=0.02).rotate(smear_deg * galsim.degrees)
        return galsim.Convolve(airy, jitter, line)
    raise ValueError(f"unknown PSF kind {kind!r}")


def psf_kernel(psf: dict, oversample: int) -> np.ndarray | None:
    """The PSF on the oversampled grid, an odd square of unit sum; None for no PSF."""
    obj = psf_object(**psf)
    if obj is None:
        return None
    n = 2 * STAMP_HALF_PX * oversample + 1
    stamp = obj.drawImage(nx=n, ny=n, scale=1.0 / oversample, method="no_pixel")
    kernel = np.asarray(stamp.array, dtype=np.float64)
    return kernel / kernel.sum()


def blur_and_bin(radiance: np.ndarray, kernel: np.ndarray | None, oversample: int
                 ) -> np.ndarray:
    """Convolve the oversampled radiance with the kernel, then average each
    ``oversample x oversample`` block into one output pixel."""
    from scipy.signal import fftconvolve

    out = radiance if kernel is None else fftconvolve(radiance, kernel, mode="same")
    n = out.shape[0] // oversample
    return out.reshape(n, oversample, n, oversample).mean(axis=(1, 3))


def detector(radiance: np.ndarray, rng: np.random.Generator, albedo_dn: float, sky_dn: float,
             gain_e_per_dn: float | None, read_noise_dn: float) -> np.ndarray:
    """DN image: ``albedo_dn`` per unit radiance over ``sky_dn``, shot noise at
    ``gain_e_per_dn`` electrons per DN (None: none) and Gaussian read noise."""
    dn = albedo_dn * radiance + sky_dn
    if gain_e_per_dn is not None:
        dn = rng.poisson(np.clip(dn, 0.0, None) * gain_e_per_dn) / gain_e_per_dn
    if read_noise_dn > 0.0:
        dn = dn + rng.normal(0.0, read_noise_dn, dn.shape)
    return dn
