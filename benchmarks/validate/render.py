"""Mitsuba 3 renders of a body under a directional Sun, seen by an orthographic camera.

The sensor is ``orthographic`` with a ``box`` reconstruction filter (each
film pixel is the area integral of the radiance over the pixel) and a
``stratified`` sampler; the integrator is ``direct`` (one bounce: the Sun is
a ``directional`` emitter, a delta light, so each hit's shading is exact and
the only Monte Carlo noise is the sample's position in its pixel). The
variant is ``scalar_rgb`` on one thread. Film pixels come out as luminance.

Units: the Sun's irradiance is ``pi``, so a Lambert surface of reflectance
``A`` reads ``A cos i`` (the profiles page's law, albedo ``A``), Minnaert
``A cos(i)^k cos(e)^(k-1)``. Bodies:

* a sphere (Mitsuba's analytic ``sphere``);
* a triaxial ellipsoid: a UV-sphere mesh with a ``to_world`` scale and
  rotation (Mitsuba's ``sphere`` accepts no non-uniform scale);
* a mesh with craters and topography: the UV sphere displaced radially,
  written as PLY and loaded.

Surfaces: ``diffuse`` (Lambert, optionally with a bitmap albedo texture) and a
Minnaert BSDF written here as a Python plugin.
"""

from __future__ import annotations

import math
import os
import tempfile
from dataclasses import dataclass, field

import numpy as np

from .geometry import rotation_matrix, sun_vector_world, world_xy

BODY_DEPTH = 1.0e3  # world Z of the body's centre (the camera is at Z = 0)

_mi = None


def mitsuba():
    """Mitsuba in ``scalar_rgb`` on one Dr.Jit thread, with the Minnaert plugin registered."""
    global _mi
    if _mi is None:
        import drjit as dr
        import mitsuba as mi

        mi.set_variant("scalar_rgb")
        dr.set_thread_count(1)
        mi.register_bsdf("minnaert", _minnaert_class(mi))
        _mi = mi
    return _mi


def _minnaert_class(mi):
    """The Minnaert BSDF class for this Mitsuba (defined once the variant is set)."""

    class Minnaert(mi.BSDF):
        """Minnaert's law: ``f cos i = (A / pi) cos(i)^k cos(e)^(k - 1)``.

        Reciprocal (``f = (A / pi) (cos i cos e)^(k - 1)``). ``si.wi`` is the
        direction toward the viewer (``e``), ``wo`` toward the light (``i``).
        Sampled as a cosine-weighted hemisphere.
        """

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.k = float(props.get("k", 1.0))
            self.albedo = float(props.get("albedo", 1.0))
            self.m_flags = mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
            self.m_components = [self.m_flags]

        def _value(self, cos_e, cos_i):
            if cos_e <= 0.0 or cos_i <= 0.0:
                return 0.0
            return self.albedo / math.pi * cos_i ** self.k * cos_e ** (self.k - 1.0)

        def sample(self, ctx, si, sample1, sample2, active=True):
            bs = mi.BSDFSample3f()
            wo = mi.warp.square_to_cosine_hemisphere(sample2)
            bs.wo = wo
            bs.pdf = mi.warp.square_to_cosine_hemisphere_pdf(wo)
            bs.eta = 1.0
            bs.sampled_type = +mi.BSDFFlags.DiffuseReflection
            bs.sampled_component = 0
            value = self._value(mi.Frame3f.cos_theta(si.wi), mi.Frame3f.cos_theta(wo))
            return bs, mi.Color3f(value / bs.pdf if bs.pdf > 0.0 else 0.0)

        def eval(self, ctx, si, wo, active=True):
            return mi.Color3f(self._value(mi.Frame3f.cos_theta(si.wi), mi.Frame3f.cos_theta(wo)))

        def pdf(self, ctx, si, wo, active=True):
            if mi.Frame3f.cos_theta(wo) <= 0.0:
                return 0.0
            return mi.warp.square_to_cosine_hemisphere_pdf(wo)

        def eval_pdf(self, ctx, si, wo, active=True):
            return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

        def traverse(self, callback):
            pass

        def to_string(self):
            return f"Minnaert[k={self.k}, albedo={self.albedo}]"

    return lambda props: Minnaert(props)


@dataclass(frozen=True)
class Body:
    """What to render: the body's shape and surface, and the Sun.

    Attributes
    ----------
    center_vu : tuple of float
        The body's centre in the output frame, ``(v, u)`` pixels.
    radius_px : float
        Sphere radius (the mean radius of a mesh), output pixels.
    phase_deg, illumination_deg : float
        The Sun, in dtalign's convention (:mod:`.geometry`).
    shape : {"sphere", "ellipsoid", "mesh"}
    axes_px, angles_deg : tuple of 3 floats
        The ellipsoid's semi-axes and the rotation of its principal axes.
    mesh_heights : ndarray or None
        Relative radial displacement of each UV-sphere vertex (``"mesh"``).
    law : {"lambert", "minnaert"}
    minnaert_k : float
    albedo : float
    albedo_texture : ndarray or None
        An (H, W) albedo map over the sphere's (longitude, latitude) UVs,
        multiplying ``albedo``.
    glow : float
        Radiance the body emits itself (an ``area`` emitter), in the same units
        as the reflected light: a night side above the sky.
    """

    center_vu: tuple[float, float]
    radius_px: float
    phase_deg: float
    illumination_deg: float
    shape: str = "sphere"
    axes_px: tuple[float, float, float] = (1.0, 1.0, 1.0)
    angles_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mesh_heights: np.ndarray | None = field(default=None, repr=False)
    law: str = "lambert"
    minnaert_k: float = 1.0
    albedo: float = 1.0
    albedo_texture: np.ndarray | None = field(default=None, repr=False)
    glow: float = 0.0


#: UV-sphere resolution of the ellipsoid and crater meshes: (rings, segments).
MESH_RINGS, MESH_SEGMENTS = 360, 720


def uv_sphere(rings: int = MESH_RINGS, segments: int = MESH_SEGMENTS
              ) -> tuple[np.ndarray, np.ndarray]:
    """Unit UV sphere: vertex directions (poles included) and triangle indices."""
    theta = np.linspace(0.0, math.pi, rings + 1)[1:-1]
    phi = np.linspace(0.0, 2 * math.pi, segments, endpoint=False)
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    ring = np.stack([st * np.cos(phi), st * np.sin(phi), ct * np.ones_like(phi)],
                    axis=-1).reshape(-1, 3)
    verts = np.concatenate([[[0.0, 0.0, 1.0]], ring, [[0.0, 0.0, -1.0]]])
    idx = 1 + np.arange((rings - 1) * segments).reshape(rings - 1, segments)
    nxt = np.roll(idx, -1, axis=1)
    faces = [np.stack([np.zeros(segments, int), nxt[0], idx[0]], axis=1)]
    a, b, c, d = idx[:-1], nxt[:-1], idx[1:], nxt[1:]
    faces += [np.stack([a, b, c], axis=-1).reshape(-1, 3), np.stack([b, d, c], axis=-1).reshape(-1, 3)]
    south = verts.shape[0] - 1
    faces.append(np.stack([np.full(segments, south), idx[-1], nxt[-1]], axis=1))
    # reversed: counter-clockwise seen from outside, so the normals point outward
    return verts, np.concatenate(faces)[:, ::-1].astype(np.int32)


def write_ply(path: str, vertices: np.ndarray, faces: np.ndarray) -> None:
    """A binary little-endian PLY of float32 vertices and int32 triangles."""
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"element vertex {len(vertices)}\nproperty float x\nproperty float y\n"
              f"property float z\nelement face {len(faces)}\n"
              "property list uchar int vertex_indices\nend_header\n")
    face_rec = np.zeros(len(faces), dtype=[("n", "u1"), ("i", "<i4", 3)])
    face_rec["n"], face_rec["i"] = 3, faces
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(np.ascontiguousarray(vertices, dtype="<f4").tobytes())
        fh.write(face_rec.tobytes())


def _bsdf(body: Body) -> dict:
    if body.law == "minnaert":
        return {"type": "minnaert", "k": body.minnaert_k, "albedo": body.albedo}
    if body.albedo_texture is not None:
        tex = np.repeat((body.albedo * body.albedo_texture)[..., None], 3, axis=2)
        reflectance = {"type": "bitmap", "bitmap": mitsuba().Bitmap(tex.astype(np.float32)),
                       "raw": True,
                       "filter_type": "bilinear"}
    else:
        reflectance = {"type": "rgb", "value": body.albedo}
    return {"type": "diffuse", "reflectance": reflectance}


def _shape(body: Body, frame_px: int, tmpdir: str) -> dict:
    mi = mitsuba()
    T = mi.ScalarTransform4f
    x, y = world_xy(body.center_vu, frame_px)
    centre = [x, y, BODY_DEPTH]
    out: dict = {"bsdf": _bsdf(body)}
    if body.glow > 0.0:
        out["emitter"] = {"type": "area", "radiance": {"type": "rgb", "value": body.glow}}
    if body.shape == "sphere":
        out.update(type="sphere", center=centre, radius=body.radius_px)
        return out
    verts, faces = uv_sphere()
    if body.shape == "mesh":
        verts = verts * (1.0 + body.mesh_heights)[:, None] * body.radius_px
        to_world = T().translate(centre)
    else:
        rot = np.eye(4)
        rot[:3, :3] = rotation_matrix(body.angles_deg)
        to_world = T().translate(centre) @ T(rot) @ T().scale(list(body.axes_px))
    path = os.path.join(tmpdir, "body.ply")
    write_ply(path, verts, faces)
    out.update(type="ply", filename=path, to_world=to_world)
    return out


def render(body: Body, frame_px: int, oversample: int = 1, spp: int = 256, seed: int = 0
           ) -> np.ndarray:
    """The body's radiance image, ``frame_px * oversample`` square, float64.

    Each film pixel is the mean radiance over its area (``box`` filter);
    ``spp`` stratified samples a film pixel (a perfect square). In the
    units of the module docstring a Lambert surface of albedo 1 reads
    ``cos i``; the sky reads 0.
    """
    mi = mitsuba()
    T = mi.ScalarTransform4f
    n = frame_px * oversample
    sun = sun_vector_world(body.phase_deg, body.illumination_deg)
    with tempfile.TemporaryDirectory(prefix="dtalign-validate-") as tmpdir:
        scene = mi.load_dict({
            "type": "scene",
            "integrator": {"type": "direct"},
            "sensor": {
                "type": "orthographic",
                "to_world": T().scale([frame_px / 2.0, frame_px / 2.0, 1.0]),
                "film": {"type": "hdrfilm", "width": n, "height": n,
                         "rfilter": {"type": "box"}, "pixel_format": "luminance"},
                "sampler": {"type": "stratified", "sample_count": spp, "seed": seed},
            },
            "sun": {"type": "directional", "direction": (-sun).tolist(),
                    "irradiance": {"type": "rgb", "value": math.pi}},
            "body": _shape(body, frame_px, tmpdir),
        })
        image = np.array(mi.render(scene), dtype=np.float64)
    return image[..., 0] if image.ndim == 3 else image


def versions() -> dict[str, str]:
    """The renderer's and the PSF library's versions, for the records."""
    import drjit
    import galsim

    mi = mitsuba()
    return {"mitsuba": mi.__version__, "drjit": drjit.__version__, "galsim": galsim.__version__}
