"""The scene families of issue 45 item 2: seeded draws and their renders.

A scene is drawn (:func:`draw`: a plain dict of numbers, JSON-ready, which
is all the fit needs besides the image) and then rendered
(:func:`render_scene`: Mitsuba, GalSim, the detector). Every scene plants
the body at a known sub-pixel centre ``center_vu``; the model is built at
``model_center_vu = center_vu - offset_vu``, so a right fit reports
``offset_vu``. Common to all: a 200 x 200 frame, radius 45-80 px, the light
direction uniform over 0-360 deg, an offset of up to 2.5 px per axis;
albedo 200 DN over a 10 DN sky; odd scenes noisy (20 e-/DN, 1 DN read
noise), even ones noise-free. Limb scenes have phase 20-70 deg, terminator
scenes 15-150 deg.

Families (what the image has that the fit is not told, if anything):

``model_right``
    a Lambert sphere, the PSF none or a Gaussian of 0.5-1.2 px.
``psf_mismatch``
    the NAC-like obscured Airy with jitter, in turn plain, with an
    anisotropic jitter, with a line smear (:mod:`.optics`).
``law_mismatch``
    a Minnaert k = 0.6-0.8 surface, fitted as Lambert.
``albedo_texture``
    Lambert with an albedo map varying by +-25 % over tens of degrees.
``craters``
    a mesh: 40 craters (depth 0.2 of their radius, a raised rim) on a
    long-wavelength relief of 0.4 % of the radius, the model its mean sphere.
``triaxial``
    an ellipsoid of axes ``R, (0.85-0.95) R, (0.8-0.9) R``, turned at random;
    the model dtalign's ellipsoid (:mod:`dtalign.api.ellipsoid`).
``night_additive``
    Lambert plus a uniform glow of 2 % of the albedo over the whole disc
    (an ``area`` emitter on the body).
``night_floor``
    Lambert shading floored at 1 % of the albedo (the per-sample maximum of
    the Lambert render and 1 % of the body's coverage).
``capped_limb``
    Minnaert k = 0.7, clipped at the disc centre's brightness (as a
    saturated frame or a simulator's cap), declared as Minnaert k = 0.7.
    Limbs only.
``heavy_noise``
    Lambert, a Gaussian PSF of 0.7 px, albedo 40 DN, 2 e-/DN, 4 DN read noise.

With a PSF, a floor or a cap the body is rendered at 4x oversampling, 16
stratified samples a sub-pixel, and binned after the PSF; otherwise at 1x
with 256 samples a pixel.
"""

from __future__ import annotations

import math

import numpy as np

FAMILIES = ("model_right", "psf_mismatch", "law_mismatch", "albedo_texture", "craters",
            "triaxial", "night_additive", "night_floor", "capped_limb", "heavy_noise")
EDGES = ("limb", "terminator")
FRAME_PX = 200


def edges_of(family: str) -> tuple[str, ...]:
    """The edges a family renders: the capped limb's are limbs only (past phase 90 the
    disc centre that sets the cap is dark)."""
    return ("limb",) if family == "capped_limb" else EDGES


def scene_rng(seed: int, family: str, edge: str, index: int) -> np.random.Generator:
    """The generator of one scene: the run's seed, the family, the edge and the index."""
    return np.random.default_rng([seed, FAMILIES.index(family), EDGES.index(edge), index])


def draw(family: str, edge: str, index: int, seed: int) -> dict:
    """The parameters of one scene (no rendering): a JSON-ready dict."""
    if family not in FAMILIES or edge not in edges_of(family):
        raise ValueError(f"no scene {family!r} / {edge!r}")
    rng = scene_rng(seed, family, edge, index)
    radius = float(rng.uniform(45.0, 80.0))
    phase = float(rng.uniform(20.0, 70.0) if edge == "limb" else rng.uniform(15.0, 150.0))
    ill = float(rng.uniform(0.0, 360.0))
    offset = rng.uniform(-0.5, 0.5, 2) + rng.integers(-2, 3, 2)
    centre = FRAME_PX / 2.0 + rng.uniform(-0.5, 0.5, 2)
    noisy = index % 2 == 1
    p = dict(
        family=family, edge=edge, index=index, seed=seed, frame_px=FRAME_PX,
        center_vu=centre.tolist(), offset_vu=offset.tolist(),
        model_center_vu=(centre - offset).tolist(), radius_px=radius, phase_deg=phase,
        illumination_deg=ill, shape="sphere", axes_px=[radius] * 3, angles_deg=[0.0] * 3,
        law="lambert", minnaert_k=1.0, profile_law="lambert", profile_k=None,
        psf={"kind": "none"}, glow=0.0, floor=0.0, cap=None,
        albedo_dn=200.0, sky_dn=10.0, gain_e_per_dn=20.0 if noisy else None,
        read_noise_dn=1.0 if noisy else 0.0, body_seed=int(rng.integers(2**31)),
        noise_seed=int(rng.integers(2**31)),
    )
    if family == "model_right":
        if index % 4 >= 2:
            p["psf"] = {"kind": "gaussian", "sigma": float(rng.uniform(0.5, 1.2))}
    elif family == "psf_mismatch":
        kind = ("nac", "nac_aniso", "nac_smear")[index % 3]
        psf = {"kind": kind, "sigma": float(rng.uniform(0.3, 0.7))}
        if kind == "nac_aniso":
            psf.update(g1=float(rng.uniform(-0.15, 0.15)), g2=float(rng.uniform(-0.15, 0.15)))
        if kind == "nac_smear":
            psf.update(smear_px=float(rng.uniform(1.0, 2.0)),
                       smear_deg=float(rng.uniform(0.0, 180.0)))
        p["psf"] = psf
    elif family == "law_mismatch":
        p.update(law="minnaert", minnaert_k=float(rng.uniform(0.6, 0.8)))
    elif family == "triaxial":
        p.update(shape="ellipsoid",
                 axes_px=[radius, radius * float(rng.uniform(0.85, 0.95)),
                          radius * float(rng.uniform(0.8, 0.9))],
                 angles_deg=rng.uniform(0.0, 360.0, 3).tolist())
    elif family == "craters":
        p["shape"] = "mesh"
    elif family == "night_additive":
        p["glow"] = 0.02
    elif family == "night_floor":
        p["floor"] = 0.01
    elif family == "capped_limb":
        p.update(law="minnaert", minnaert_k=0.7, profile_law="minnaert", profile_k=0.7,
                 cap=math.cos(math.radians(phase)) ** 0.7)
    elif family == "heavy_noise":
        p.update(psf={"kind": "gaussian", "sigma": 0.7}, albedo_dn=40.0, gain_e_per_dn=2.0,
                 read_noise_dn=4.0)
    p["oversample"] = 4 if (p["psf"]["kind"] != "none" or p["floor"] or p["cap"]) else 1
    p["spp"] = 16 if p["oversample"] > 1 else 256
    return p


def albedo_map(rng: np.random.Generator, shape: tuple[int, int] = (128, 256)) -> np.ndarray:
    """A smooth albedo map over (latitude, longitude), 1 +- 0.25: a sum of low-order waves."""
    lat = np.linspace(0.0, math.pi, shape[0])[:, None]
    lon = np.linspace(0.0, 2 * math.pi, shape[1], endpoint=False)[None, :]
    field = np.zeros(shape)
    for _ in range(12):
        m, n = rng.integers(1, 7, 2)
        field += np.cos(m * lon + rng.uniform(0, 2 * math.pi)) * np.cos(n * lat + rng.uniform(0, 2 * math.pi))
    return 1.0 + 0.25 * field / np.abs(field).max()


def crater_heights(rng: np.random.Generator, directions: np.ndarray, n_craters: int = 40
                   ) -> np.ndarray:
    """Relative radial heights at unit ``directions``: craters on a gentle relief.

    A crater of angular radius ``a`` (0.03-0.12 rad) is a parabolic bowl of
    depth ``0.2 a`` inside ``a`` and a rim of height ``0.04 a`` decaying as a
    Gaussian of width ``0.3 a`` outside; the relief is 8 Gaussian swells of
    0.4 % of the radius and 0.6 rad width.
    """
    h = np.zeros(len(directions))
    for _ in range(8):
        c = rng.normal(size=3)
        c /= np.linalg.norm(c)
        ang = np.arccos(np.clip(directions @ c, -1, 1))
        h += rng.uniform(-0.004, 0.004) * np.exp(-(ang / 0.6) ** 2)
    for _ in range(n_craters):
        c = rng.normal(size=3)
        c /= np.linalg.norm(c)
        a = rng.uniform(0.03, 0.12)
        ang = np.arccos(np.clip(directions @ c, -1, 1))
        inside = ang < a
        h += np.where(inside, 0.2 * a * ((ang / a) ** 2 - 1.0) + 0.04 * a,
                      0.04 * a * np.exp(-((ang - a) / (0.3 * a)) ** 2))
    return h


def render_scene(p: dict) -> np.ndarray:
    """The scene's image in DN (float64): render, PSF, bin, detector."""
    from . import optics
    from .render import Body, render, uv_sphere

    rng = np.random.default_rng(p["body_seed"])
    kwargs: dict = {}
    if p["family"] == "albedo_texture":
        kwargs["albedo_texture"] = albedo_map(rng)
    if p["shape"] == "mesh":
        kwargs["mesh_heights"] = crater_heights(rng, uv_sphere()[0])
    body = Body(center_vu=tuple(p["center_vu"]), radius_px=p["radius_px"],
                phase_deg=p["phase_deg"], illumination_deg=p["illumination_deg"],
                shape=p["shape"], axes_px=tuple(p["axes_px"]), angles_deg=tuple(p["angles_deg"]),
                law=p["law"], minnaert_k=p["minnaert_k"], glow=p["glow"], **kwargs)
    f, n = p["oversample"], p["frame_px"]
    radiance = render(body, n, f, p["spp"], seed=p["body_seed"] % 2**16)
    if p["floor"]:
        coverage = render(Body(center_vu=body.center_vu, radius_px=body.radius_px,
                               phase_deg=0.0, illumination_deg=0.0, albedo=0.0, glow=1.0),
                          n, f, p["spp"], seed=p["body_seed"] % 2**16)
        radiance = np.maximum(radiance, p["floor"] * coverage)
    if p["cap"] is not None:
        radiance = np.minimum(radiance, p["cap"])
    image = optics.blur_and_bin(radiance, optics.psf_kernel(p["psf"], f), f)
    return optics.detector(image, np.random.default_rng(p["noise_seed"]), p["albedo_dn"],
                           p["sky_dn"], p["gain_e_per_dn"], p["read_noise_dn"])
