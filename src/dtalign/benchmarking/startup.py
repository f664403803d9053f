"""Start-up section: fresh subprocesses importing dtalign and fitting once.

Measures ``import dtalign`` and the first fit with a warm on-disk cache;
with ``full`` also the first-run compile time (empty ``NUMBA_CACHE_DIR``)
and whether a read-only install still caches (Numba's user-wide cache).
"""

from __future__ import annotations

import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from .workloads import FIRST_FIT_TARGET_S, IMPORT_TARGET_S

# The subprocess of the start-up section: argv = [input dir, "warm"|"cold"].
_STARTUP_SCRIPT = r"""
import json, sys, time
t_np = time.perf_counter()
import numpy as np
t_np = time.perf_counter() - t_np
d = sys.argv[1]
a = {k: np.load(f"{d}/{k}.npy") for k in ("dt", "grad", "verts", "norms", "sigmas", "image")}
t0 = time.perf_counter()
import dtalign
t_import = time.perf_counter() - t0
imported_numba = "numba" in sys.modules
def fit():
    edge = a["dt"] <= 0.5
    mask = dtalign.build_polyline_mask(a["verts"], a["dt"].shape)
    seed = dtalign.coarse_ncc_search(edge, mask, (30, 30))
    return dtalign.lm_subpixel_refine(
        vertices_vu=a["verts"], normals_vu=a["norms"], sigma_normal_per_vertex_px=a["sigmas"],
        image_edge_dt=a["dt"], image_gradient_vu=a["grad"],
        initial_offset_vu=(float(seed[0]), float(seed[1])))
fit()
t_first = time.perf_counter() - t0
t1 = time.perf_counter(); fit(); t_second = time.perf_counter() - t1
t1 = time.perf_counter(); dtalign.compute_all_image_derivatives(a["image"], 2.0)
t_deriv = time.perf_counter() - t1
import numba, os
probe = os.path.join(os.path.dirname(dtalign.__file__), ".dtalign-write-probe")
try:
    open(probe, "w").close()
    os.remove(probe)
    writable = True
except OSError:
    writable = False
print(json.dumps({"package_writable": writable, "import_s": t_import, "import_numpy_s": t_np, "import_loads_numba": imported_numba,
                  "first_fit_s": t_first, "second_fit_s": t_second,
                  "first_derivatives_64px_s": t_deriv, "numba_cache_dir": numba.config.CACHE_DIR,
                  "dtalign_file": dtalign.__file__}))
"""


def _subprocess(
    args: list[str], env: dict[str, str], readonly: Path | None = None
) -> dict[str, Any]:
    """Run ``python args`` and parse the JSON it prints last.

    With ``readonly``, that directory is made read-only for the child: by
    permissions, and, when running as root (who ignores permissions), by a
    read-only bind mount in a private mount namespace (``unshare -m``).
    """
    cmd = [sys.executable, *args]
    if readonly is not None and hasattr(os, "geteuid") and os.geteuid() == 0:
        if shutil.which("unshare"):
            script = ('mount --bind "$1" "$1" && mount -o remount,ro,bind "$1" "$1" '
                      '|| exit 97; shift; exec "$@"')
            cmd = ["unshare", "-m", "sh", "-c", script, "sh", str(readonly), *cmd]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    if proc.returncode in (1, 97) and cmd[0] == "unshare":  # no mount rights: permissions only
        t0 = time.perf_counter()
        proc = subprocess.run(cmd[7:], env=env, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"start-up subprocess failed:\n{proc.stderr[-2000:]}")
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    result["process_wall_s"] = wall
    return dict(result)


def _count_files(root: Path, suffixes: tuple[str, ...] = (".nbi", ".nbc")) -> int:
    return sum(1 for p in root.rglob("*") if p.suffix in suffixes) if root.exists() else 0


def measure_startup(full: bool) -> dict[str, Any]:
    """Fresh-process start-up: import, first fit with a warm cache; optionally cold/read-only."""
    import dtalign.reference as reference
    import dtalign.scenes as scenes

    pkg_dir = Path(__file__).resolve().parents[1]
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(pkg_dir.parent), env.get("PYTHONPATH", "")])
    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="dtalign-startup-") as tmp:
        scene = scenes.disc_scene()
        _, dt, grad = reference.compute_all_image_derivatives(scene.image, scene.noise_sigma)
        p = scene.polyline
        arrays = {"dt": dt, "grad": grad, "verts": p.vertices_vu, "norms": p.normals_vu,
                  "sigmas": p.sigmas, "image": scene.image[:64, :64].copy()}
        for key, value in arrays.items():
            np.save(Path(tmp) / f"{key}.npy", value)
        script = ["-c", _STARTUP_SCRIPT, tmp]
        _subprocess(script, env)  # make sure the cache is warm
        warm = [_subprocess(script, env) for _ in range(3)]
        out["warm"] = warm[-1]
        out["import_s"] = statistics.median(r["import_s"] for r in warm)
        out["first_fit_s"] = statistics.median(r["first_fit_s"] for r in warm)
        out["import_loads_numba"] = any(r["import_loads_numba"] for r in warm)
        if not full:
            return out
        # Cold: an empty NUMBA_CACHE_DIR, then the same directory warm.
        # Read-only install: a copy of the package without write permission,
        # Numba falling back to its user-wide cache (XDG_CACHE_HOME here).
        cold_env = dict(env, NUMBA_CACHE_DIR=str(Path(tmp) / "numba-cache"))
        ro_root = Path(tmp) / "ro"
        shutil.copytree(pkg_dir, ro_root / "dtalign", ignore=shutil.ignore_patterns("__pycache__"))
        xdg = Path(tmp) / "xdg"
        ro_env = dict(env, PYTHONPATH=str(ro_root), XDG_CACHE_HOME=str(xdg))
        ro_env.pop("NUMBA_CACHE_DIR", None)
        for path in [ro_root, *ro_root.rglob("*")]:
            path.chmod(path.stat().st_mode & ~0o222)
        try:
            # The two compiling runs are independent: one per core.
            with ThreadPoolExecutor(max_workers=2) as pool:
                cold = pool.submit(_subprocess, script, cold_env)
                ro_first = pool.submit(_subprocess, script, ro_env, readonly=ro_root)
                out["cold"], out["readonly_first"] = cold.result(), ro_first.result()
            out["cold_then_warm"] = _subprocess(script, cold_env)
            out["readonly_second"] = _subprocess(script, ro_env, readonly=ro_root)
            out["readonly_files_in_package"] = _count_files(ro_root)
            out["readonly_files_in_user_cache"] = _count_files(xdg)
            out["readonly_user_cache_dir"] = str(xdg / "numba")
        finally:
            for path in [ro_root, *ro_root.rglob("*")]:
                path.chmod(path.stat().st_mode | 0o200)
        out["compile_s"] = out["cold"]["first_fit_s"] + out["cold"]["first_derivatives_64px_s"]
        out["readonly_package_was_writable"] = out["readonly_first"]["package_writable"]
        out["readonly_caches"] = (
            not out["readonly_package_was_writable"]
            and out["readonly_files_in_user_cache"] > 0
            and out["readonly_files_in_package"] == 0
            and out["readonly_second"]["first_fit_s"] < 0.5 * out["readonly_first"]["first_fit_s"]
        )
    return out


def _startup_rows(s: dict[str, Any]) -> list[dict[str, Any]]:
    rows = [
        {"name": "import_dtalign", "kind": "startup", "dtalign_s": s["import_s"],
         "target_s": IMPORT_TARGET_S, "passed": s["import_s"] < IMPORT_TARGET_S,
         "description": "import dtalign, fresh process"},
        {"name": "first_fit_warm_cache", "kind": "startup", "dtalign_s": s["first_fit_s"],
         "target_s": FIRST_FIT_TARGET_S, "passed": s["first_fit_s"] < FIRST_FIT_TARGET_S,
         "description": "import + first mask/coarse/LM fit, warm Numba cache"},
    ]
    if "compile_s" in s:
        rows.append({"name": "first_run_compile", "kind": "startup", "dtalign_s": s["compile_s"],
                     "target_s": None, "passed": True,
                     "description": "fit + derivatives, empty NUMBA_CACHE_DIR"})
        rows.append({"name": "readonly_install_caches", "kind": "startup",
                     "dtalign_s": s["readonly_second"]["first_fit_s"], "target_s": None,
                     "passed": bool(s["readonly_caches"]),
                     "description": "read-only package: second process first fit"})
    return rows
