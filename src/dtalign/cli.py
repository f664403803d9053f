"""The ``dtalign`` command line (also ``python -m dtalign``).

Subcommands: ``demo`` (fit the synthetic disc scene and report each stage),
``fit IMAGE POLYLINE ...`` (fit model polylines to images, through
:func:`dtalign.pipeline.batch.fit_images`), ``overlay PNG`` (split a
Cassini summary PNG into an image and a polyline CSV), ``bench`` (the quick
benchmark table) and ``archive MANIFEST --out STORE`` (a campaign on Dask:
:mod:`dtalign.archive`). :doc:`/cli` describes their options, their output
and the exit statuses.

Each subcommand is a row of the table ``_COMMANDS``: its handler, its help,
its description and its options. :func:`main` parses its arguments
intermixed (options anywhere) and calls its handler, whose ``CLIError`` (or
``OSError``, ``ValueError`` ...) is printed as one line.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import glob
import importlib.util
import json
import logging
import math
import os
import pickle
import re
import sys
import time
from collections import Counter
from collections.abc import Callable, Generator, Sequence
from pathlib import Path
from typing import Any

from .api.constants import DEFAULT_SEARCH_WINDOW_VU

__all__ = ["build_parser", "main"]

PROG = "dtalign"

#: Exit status on Ctrl-C: 128 + SIGINT, what shells report for an interrupted job.
EXIT_INTERRUPTED = 130

#: Exit status when every input was read and fitted but some fit's status is
#: ``failed``; 1 stays "an error stopped the work".
EXIT_FIT_FAILED = 3

#: Exit status when no fit failed but some is ``suspect`` or ``ambiguous``: a
#: pose was measured, but a pipeline should not trust it unread.
EXIT_FIT_DOUBTFUL = 4

#: Printed before the first compiled call when the kernels' cache looks cold:
#: a first run otherwise sits silent for the whole compilation.
COMPILE_NOTICE = (
    f"{PROG}: compiling the kernels for first use (about 1-3 minutes, once: "
    "the machine code is then cached on disk) ..."
)

_NUMBER = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")

#: Half-size of a ``--zoom`` panel unless ``--zoom-half`` says otherwise (px):
#: wide enough to show the edge and the model's residual at a glance.
DEFAULT_ZOOM_HALF_PX = 20.0


class CLIError(Exception):
    """A user-facing error: printed as one line, exit status 1."""


def _fail(message: str) -> int:
    print(f"{PROG}: error: {message}", file=sys.stderr)
    return 1


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().replace("\n", " ")
    if isinstance(exc, FileNotFoundError) and not text:
        text = "file not found"
    return text or type(exc).__name__


# ---------------------------------------------------------------------------
# Messages, progress, output
# ---------------------------------------------------------------------------


class _Messages:
    """Status lines on standard error, through tqdm's writer while a bar is
    shown (a plain ``print`` would land on the bar's line): ``_MESSAGES``."""

    def __init__(self) -> None:
        self.bar: Any = None

    def say(self, text: str) -> None:
        if self.bar is not None:
            self.bar.write(text, file=sys.stderr)
        else:
            print(text, file=sys.stderr)


class _Warnings(logging.Handler):
    """Says the ``dtalign`` logger's records as ``dtalign: warning: LABEL: ...``,
    ``label`` naming the input being fitted."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.label = ""

    def emit(self, record: logging.LogRecord) -> None:
        where = f"{self.label}: " if self.label else ""
        _MESSAGES.say(f"{PROG}: {record.levelname.lower()}: {where}{record.getMessage()}")


_MESSAGES = _Messages()
_WARNINGS = _Warnings()


@contextlib.contextmanager
def _progress(total: int, enabled: bool) -> Generator[Any, None, None]:
    """A batch's ``progress(done, total)``: a tqdm bar, or plain ``[done/total]``
    lines without tqdm (None when not ``enabled``)."""
    if not enabled:
        yield None
        return
    from ._progress import tqdm_bar

    bar = tqdm_bar(total, unit="image", desc="fitting")
    if bar is None:  # tqdm is optional
        yield lambda done, total: _MESSAGES.say(f"[{done}/{total}] images fitted")
        return
    _MESSAGES.bar = bar
    try:
        yield lambda done, _: bar.update(done - bar.n)
    finally:
        _MESSAGES.bar = None
        bar.close()


def _check_output_file(path: str | Path, option: str) -> Path:
    """Fail now, in one line, if ``path`` cannot be written later."""
    p = Path(path)
    if p.is_dir():
        raise CLIError(f"{option} {p}: is a directory")
    folder = p.parent if str(p.parent) else Path(".")
    if not folder.is_dir():
        raise CLIError(f"{option} {p}: folder {folder} does not exist")
    if not os.access(folder, os.W_OK):
        raise CLIError(f"{option} {p}: folder {folder} is not writable")
    return p


def _result(text: str, path: Path | None) -> None:
    """The command's result: printed, or written to ``--output FILE``."""
    if path is None:
        print(text)
    else:
        path.write_text(text + "\n", encoding="utf-8")
        _MESSAGES.say(f"{PROG}: wrote {path}")


def _cache_tag() -> object:
    """What each of dtalign's Numba index files starts with, or None if unknown."""
    try:
        import numba

        from ._numba_cache import CACHE_FORMAT
    except (ImportError, AttributeError):
        return None
    return (numba.__version__, CACHE_FORMAT)


def _kernel_cache_cold(kernels: Path | None = None) -> bool:
    """Whether the first compiled call will probably compile (a few ``stat``).

    True when the kernels' ``__pycache__`` holds no current index (one of
    another Numba version or cache format is stale), or an index is older
    than its kernel's source. Only the cache beside the source is looked at.
    """
    if kernels is None:
        kernels = Path(__file__).resolve().parent / "_kernels"
    tag = _cache_tag()
    newest: dict[str, float] = {}  # each kernel module's newest current index
    try:
        for entry in (kernels / "__pycache__").iterdir():
            # our own cache file's tag, read as Numba reads it: another one is stale
            if entry.suffix == ".nbi" and (tag is None or pickle.loads(entry.read_bytes()) == tag):
                module = entry.name.split(".", 1)[0]
                newest[module] = max(newest.get(module, 0.0), entry.stat().st_mtime)
    except (OSError, pickle.UnpicklingError, EOFError, ValueError):
        return True

    def edited(module: str, stamp: float) -> bool:
        try:
            return (kernels / f"{module}.py").stat().st_mtime > stamp
        except OSError:
            return False

    return not newest or any(edited(m, stamp) for m, stamp in newest.items())


def _jit_disabled() -> bool:
    """Numba's own ``NUMBA_DISABLE_JIT`` setting: the kernels then run as Python."""
    try:
        from numba.core import config
    except ImportError:
        return False
    return bool(getattr(config, "DISABLE_JIT", False))


def _compile_notice(messages: _Messages) -> None:
    # With the JIT disabled nothing compiles, whatever the cache holds.
    if not _jit_disabled() and _kernel_cache_cold():
        messages.say(COMPILE_NOTICE)


def _pair_arg(text: str, option: str, example: str = "120,340") -> tuple[float, float]:
    """``"A,B"`` -> ``(A, B)`` for options such as ``--zoom V,U``."""
    parts = text.split(",")
    if len(parts) != 2:
        raise CLIError(f"{option} takes two numbers separated by a comma (e.g. {example}), got {text!r}")
    try:
        return float(parts[0]), float(parts[1])
    except ValueError:
        raise CLIError(f"{option} takes numbers, got {text!r}") from None


def _outputs(args: argparse.Namespace) -> tuple[list[tuple[float, float]], Path | None, Path | None]:
    """``--zoom``, ``--zoom-half``, ``--plot`` and ``--output`` checked before any
    work: the zoom points, the plot's path and the output's (None if not given)."""
    points = [_pair_arg(z, "--zoom") for z in (args.zoom or ())]
    if not all(math.isfinite(x) for pt in points for x in pt):
        raise CLIError("--zoom points must be finite")
    if not (math.isfinite(args.zoom_half) and args.zoom_half > 0):
        raise CLIError(f"--zoom-half must be a positive number, got {args.zoom_half}")
    plot = None
    if args.plot:
        plot = _check_output_file(args.plot, "--plot")
        if importlib.util.find_spec("matplotlib") is None:
            raise CLIError("--plot needs matplotlib: pip install matplotlib")
    return points, plot, None if args.output is None else _check_output_file(args.output, "--output")


def _plot(image: Any, vertices: Any, fit: Any, path: str | Path, label: str,
          zooms: list[tuple[float, float]], zoom_half: float) -> None:
    from .plotting import plot_fit

    plot_fit(image, vertices, fit, path, zoom_vu=zooms or None, zoom_half_px=zoom_half)
    _MESSAGES.say(f"{label}: wrote {path}")


def _fmt(x: float, digits: int = 3) -> str:
    return f"{x:.{digits}f}" if math.isfinite(x) else ("inf" if x > 0 else "-inf")


def _settled_text(fit: Any) -> str:
    """How the LM ended, in a few words: converged, settled, or still moving."""
    if fit.lm.converged:
        return "converged"
    s = fit.settling
    if s is None:
        return "not converged"
    if s.settled:
        return f"settled (moved {s.shift_px:.2g} px over its last {s.iterations})"
    return f"NOT settled (moved {s.shift_px:.3g} px over its last {s.iterations})"


def _sigma_text(fit: Any, sigma: float | None, digits: int) -> str:
    """``± sigma``, or the words of a failed fit's sigma, which is no measurement."""
    from .pipeline.status import UNMEASURED_TEXT

    return f"sigma {UNMEASURED_TEXT}" if fit.failed else f"± {_fmt(sigma or 0.0, digits)}"


# ---------------------------------------------------------------------------
# demo
# ---------------------------------------------------------------------------


def _cmd_demo(args: argparse.Namespace) -> int:
    for option, value, least in (("--n-vertices", args.n_vertices, 3), ("--window", args.window, 0),
                                 ("--repeat", args.repeat, 1)):
        if value < least:
            raise CLIError(f"{option} must be >= {least}, got {value}")
    zooms, _, output = _outputs(args)  # the plot is written to --plot as given
    save_dir = _save_folder(Path(args.save)) if args.save else None

    import numpy as np

    import dtalign.pipeline as pipeline
    import dtalign.scenes as scenes

    rotation = 0.0 if args.rotation is None else float(args.rotation)
    t0 = time.perf_counter()
    scene = scenes.disc_scene(
        n_vertices=args.n_vertices, rotation_rad=rotation, seed=args.seed, search_window=args.window
    )
    t_scene = time.perf_counter() - t0
    poly, rotating = scene.polyline, args.rotation is not None
    if save_dir is not None:  # a sample input for fit
        from .io.files import save_polyline_csv

        image, polyline = save_dir / "demo.npy", save_dir / "demo.csv"
        np.save(image, scene.image)
        save_polyline_csv(polyline, poly)
        _MESSAGES.say(f"demo: wrote {image} (image) and {polyline} (polyline); try: {PROG} fit "
                      f"{image} {polyline} --window {args.window}{' --rotation' if rotating else ''}")
    _compile_notice(_MESSAGES)
    for _ in range(args.repeat):
        fit = pipeline.fit_polyline(
            scene.image, poly.vertices_vu, poly.normals_vu, poly.sigmas,
            noise_sigma=scene.noise_sigma,
            search_window_vu=scene.search_window_vu, fit_rotation=rotating,
            pivot_vu=scene.pivot_vu, pivot_distance_px=scene.pivot_distance_px if rotating else None,
            trust_region_px=1.0)
    noise_est = pipeline.estimate_noise_sigma(scene.image)
    if args.plot:
        _plot(scene.image, poly.vertices_vu, fit, args.plot, "demo", zooms, args.zoom_half)
    _result(json.dumps({
        "true_offset_vu": list(scene.true_offset_vu), "true_rotation_rad": scene.true_rotation_rad,
        "noise_sigma_true": scene.noise_sigma, "noise_sigma_estimated": noise_est,
        "fit": fit.to_dict(), "scene_s": t_scene}, indent=2) if args.json
        else _demo_text(scene, fit, noise_est, args), output)
    return 0


def _save_folder(folder: Path) -> Path:
    """``--save``'s folder, made if need be; refused now if it cannot be written."""
    if folder.exists() and not folder.is_dir():
        raise CLIError(f"--save {folder}: exists and is not a directory")
    folder.mkdir(parents=True, exist_ok=True)
    if not os.access(folder, os.W_OK):
        raise CLIError(f"--save {folder}: folder is not writable")
    return folder


def _demo_text(scene: Any, fit: Any, noise_est: float, args: argparse.Namespace) -> str:
    """The demo's report: the scene, the truth, the fit against it, and the stage times."""
    from .api.constants import DEFAULT_LM_MAX_ITERATIONS
    from .pipeline.status import UNMEASURED_TEXT

    poly, t = scene.polyline, fit.timings_s
    h, w = scene.image.shape
    tv, tu = scene.true_offset_vu
    (dv, du), (sv, su) = fit.offset_vu, fit.sigma_vu
    (sv2, su2) = fit.uncertainty.sigma_vu_scaled
    fitted = (f"dv = {_fmt(dv, 4)}   du = {_fmt(du, 4)} px, sigma {UNMEASURED_TEXT}"
              if fit.failed else
              f"dv = {_fmt(dv, 4)} ± {_fmt(sv, 4)}   du = {_fmt(du, 4)} ± {_fmt(su, 4)} px (1 sigma)")
    scaled = (f"sigma {UNMEASURED_TEXT}" if fit.failed else
              f"± {_fmt(sv2, 4)}, ± {_fmt(su2, 4)} px (the M-estimator's 1 sigma scaled by the "
              f"residuals, variance factor {_fmt(fit.uncertainty.variance_factor, 4)})")
    lines = [
        f"scene     : {h} x {w} disc, radius 150 px, {len(poly)} limb vertices, seed {args.seed}",
        f"noise     : sigma {scene.noise_sigma:g} DN (estimated from the image: {noise_est:.3f})",
        f"true      : offset (dv, du) = ({tv:.3f}, {tu:.3f}) px"
        + (f", rotation {scene.true_rotation_rad:.5f} rad" if args.rotation is not None else ""),
        f"coarse    : offset (dv, du) = {fit.coarse_offset_vu} (window ±{args.window})",
        f"fitted    : {fitted}",
        f"scaled    : {scaled}",
    ]
    if fit.fit_rotation:
        lines.append(f"rotation  : {fit.rotation_rad:.6f} "
                     f"{_sigma_text(fit, fit.sigma_rotation_rad, 6)} rad")
    lines.append(f"error     : dv {dv - tv:+.4f}, du {du - tu:+.4f} px")
    if fit.observable_rank < fit.n_params:
        lines.append(f"observable: rank {fit.observable_rank}: a circle turned about its centre "
                     "looks the same, so its rotation is not measured (sigma inf)")
    first = " (first call: includes loading or compiling the kernels; try --repeat 2)"
    lines += [
        f"LM        : {fit.lm.iterations} iterations (cap {DEFAULT_LM_MAX_ITERATIONS}), "
        f"{_settled_text(fit)}, rms {_fmt(fit.lm.rms_px)} px, inliers {fit.lm.inlier_count}/{len(poly)}",
        f"status    : {fit.status}" + (f" ({', '.join(map(str, fit.reasons))})" if fit.reasons else ""),
        f"wall time : derivatives {t.get('derivatives', 0.0) * 1e3:.1f} ms, "
        f"coarse {t.get('coarse', 0.0) * 1e3:.1f} ms, lm {t.get('lm', 0.0) * 1e3:.1f} ms"
        + (first if args.repeat == 1 else ""),
    ]
    return "\n".join(lines)


# ---------------------------------------------------------------------------
# fit
# ---------------------------------------------------------------------------


@dataclasses.dataclass
class _Job:
    image: Path
    polyline: Path
    label: str = ""
    plot_name: str = ""
    colour: Any = None  # the image's colour note (dtalign.io.read_image), once read
    loaded: Any = None  # (image, polyline) once read, until its fit is reported


def _cmd_fit(args: argparse.Namespace) -> int:
    from .api.checks import search_window
    from .api.options import NAMES  # the FitOptions fields, which fit's flags set by name
    from .pipeline.batch import fit_images

    window = search_window(args.window, "--window", form="option")
    body = _body_model(args)  # a malformed --sphere is the command's error, before any image
    mask = _mask(args)  # as is an unreadable --mask
    jobs, batch = _jobs(args)
    zooms, plot_path, output = _outputs(args)
    rows: list[dict[str, Any]] = []  # one per image reported: its fit's to_dict(), or its error
    tables: list[str] = []  # a single fit's report

    def report(i: int, result: Any) -> None:  # fit_images' on_image: in input order
        job = jobs[i]
        loaded, job.loaded = job.loaded, None  # the image is not kept once reported
        row = {"image": str(job.image), "polyline": str(job.polyline), "label": job.label}
        try:
            fit = _reported(job, result, _MESSAGES)
            if plot_path is not None:
                out = plot_path
                if batch:
                    out = out.with_name(f"{out.stem}_{job.plot_name}{out.suffix or '.png'}")
                _plot(loaded[0], loaded[1].vertices_vu, fit, out, job.label, zooms, args.zoom_half)
        except (OSError, ValueError, TypeError, ImportError) as exc:
            if not batch:
                raise
            rows.append({**row, "error": _one_line(exc)})
            _MESSAGES.say(f"{PROG}: FAILED {job.label}: {_one_line(exc)}")
            return
        rows.append({**row, **fit.to_dict()})
        if not args.json and not batch:
            tables.append(_table_single(job, fit, rows[-1], args.noise_sigma is None))

    _compile_notice(_MESSAGES)
    interrupted = False
    try:
        with _progress(len(jobs), batch and not args.no_progress and not args.json) as progress:
            fit_images([functools.partial(_load, job, args, body, mask) for job in jobs],
                       search_window_vu=window, errors="collect", progress=progress,
                       on_image=report, **{k: v for k, v in vars(args).items() if k in NAMES})
    except BaseException as exc:
        # A Ctrl-C ends a batch, not the command: the rows reported before it
        # are printed (or written) and fit exits 130. A single fit's Ctrl-C
        # propagates (main says "interrupted").
        if not (batch and _is_interrupt(exc)):
            raise
        interrupted = True
    _result(json.dumps(rows if batch else rows[0], indent=2) if args.json
            else _table_batch(rows) if batch else tables[0], output)
    return _exit_code(rows, len(jobs), interrupted)


def _reported(job: _Job, result: Any, messages: _Messages) -> Any:
    """Say what image ``job`` gave (its colour note, its fit's warnings) and
    return its fit, or raise its error.

    ``result`` is :func:`~dtalign.pipeline.batch.fit_images`' for the image:
    its one fit in a list, or its error (a file that could not be read, a
    polyline that could not be fitted), raised as it is (the batch names
    the item in a note only): the row names the file.
    """
    from .pipeline.status import log_fit

    _WARNINGS.label = str(job.image)  # the pipeline's warnings about it name the file
    if job.colour is not None:  # the library's rule (dtalign.api.colour), said here
        messages.say(f"{PROG}: {'warning' if job.colour.luma else 'note'}: {job.colour.text}")
    if not isinstance(result, Exception):
        result = result[0]
    if isinstance(result, Exception):
        raise result
    log_fit(result, "fit")
    return result


def _exit_code(rows: list[dict[str, Any]], n_jobs: int, interrupted: bool) -> int:
    """The exit status of the rows reported (the worst kind of trouble decides), said."""
    if interrupted:
        _MESSAGES.say(f"{PROG}: interrupted after {len(rows)} of {n_jobs} image(s); "
                     "the rows above are the ones finished")
        return EXIT_INTERRUPTED
    status = Counter("error" if "error" in r else r["status"] for r in rows)
    for count, what, code in ((status["error"], "image(s) failed", 1),
                              (status["failed"], "fit(s) failed (status 'failed')", EXIT_FIT_FAILED),
                              (status["suspect"] + status["ambiguous"],
                               "fit(s) suspect or ambiguous", EXIT_FIT_DOUBTFUL)):
        if count:
            _MESSAGES.say(f"{PROG}: {count} of {n_jobs} {what}")
            return code
    return 0


def _is_interrupt(exc: BaseException | None) -> bool:
    """A KeyboardInterrupt, or an error it caused: a Ctrl-C that lands while
    Numba unpickles a kernel's constants comes out as a SystemError chained
    to it."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def _jobs(args: argparse.Namespace) -> tuple[list[_Job], bool]:
    """The (image, polyline) jobs and whether this is a batch."""
    if len(args.pairs) % 2:
        raise CLIError(
            "fit needs IMAGE POLYLINE pairs: got an odd number of files "
            f"({len(args.pairs)}); use --batch or --glob for images with same-stem .csv polylines"
        )
    jobs = [_Job(Path(a), Path(b)) for a, b in zip(args.pairs[::2], args.pairs[1::2], strict=True)]
    if args.batch:
        listfile = Path(args.batch)
        if not listfile.is_file():
            raise CLIError(f"batch list not found: {listfile}")
        for line in listfile.read_text(encoding="utf-8").splitlines():
            parts = line.split("#", 1)[0].split()
            if len(parts) > 2:
                raise CLIError(f"batch list {listfile}: expected 'IMAGE [POLYLINE]', got {line!r}")
            if parts:  # relative to the list's folder (an absolute path stays itself)
                img = listfile.parent / parts[0]
                jobs.append(_Job(img, listfile.parent / parts[1] if len(parts) == 2
                                 else img.with_suffix(".csv")))
    if args.glob:
        matches = sorted(p for p in glob.glob(args.glob) if not p.lower().endswith(".csv"))
        if not matches:
            raise CLIError(f"no image matches --glob {args.glob!r}")
        jobs.extend(_Job(Path(m), Path(m).with_suffix(".csv")) for m in matches)
    if not jobs:
        raise CLIError("fit needs IMAGE POLYLINE (or --batch LIST, or --glob PATTERN)")
    _label_jobs(jobs)
    return jobs, bool(args.batch or args.glob or len(jobs) > 1)


def _unique_names(paths: Sequence[Path]) -> list[str]:
    """Short names for ``paths``: the file name, with just enough parent
    folders to tell apart paths that share it (``a/disc.npy``,
    ``b/disc.npy``). Paths naming the same file keep the same name."""
    resolved = [Path(os.path.abspath(p)).parts for p in paths]
    levels = [0] * len(paths)
    while True:  # each name its file name and the last ``level`` folders
        names = ["/".join(parts[len(parts) - 1 - k :]) for parts, k in zip(resolved, levels, strict=True)]
        groups: dict[str, set[tuple[str, ...]]] = {}
        for n, parts in zip(names, resolved, strict=True):
            groups.setdefault(n, set()).add(parts)
        grow = [i for i, n in enumerate(names)
                if len(groups[n]) > 1 and levels[i] < len(resolved[i]) - 1]
        if not grow:
            return names
        for i in grow:
            levels[i] += 1


def _distinct(labels: list[str], others: list[str], sep: str) -> list[str]:
    """``labels`` made unique: a repeated label gets ``sep + other``, then ``#k``."""
    count = Counter(labels)
    out = [f"{a}{sep}{b}" if count[a] > 1 else a for a, b in zip(labels, others, strict=True)]
    count = Counter(out)
    seen: Counter[str] = Counter()
    result = []
    for a in out:
        seen[a] += 1
        result.append(f"{a}#{seen[a]}" if count[a] > 1 else a)
    return result


def _label_jobs(jobs: list[_Job]) -> None:
    """Give each job a distinct table label and plot-file name (:doc:`/cli`'s
    "Many images"): the image's file name, with parent folders when two
    images share a name, and `` + polyline`` when one image is fitted with
    several polylines; plot files use the label without the file suffixes
    unless that would make two alike (``disc.npy`` and ``disc.png``)."""
    images = _unique_names([j.image for j in jobs])
    labels = _distinct(images, _unique_names([j.polyline for j in jobs]), " + ")

    def without_suffixes(label: str, job: _Job) -> str:
        head, sep, tail = label.partition(" + ")
        if job.image.suffix and head.endswith(job.image.suffix):
            head = head[: -len(job.image.suffix)]
        tail, hash_, k = tail.partition("#")
        if job.polyline.suffix and tail.endswith(job.polyline.suffix):
            tail = tail[: -len(job.polyline.suffix)]
        return head + ("+" if sep else "") + tail + ("_" + k if hash_ else "")

    stems = [without_suffixes(label, job) for label, job in zip(labels, jobs, strict=True)]
    if len(set(stems)) < len(stems):  # e.g. disc.npy and disc.png: keep the suffixes
        stems = [label.replace(" + ", "+").replace("#", "_") for label in labels]
    for job, label, stem in zip(jobs, labels, stems, strict=True):
        job.label = label
        job.plot_name = re.sub(r"[^\w.+-]+", "_", stem)


def _mask(args: argparse.Namespace) -> Any:
    """``--mask FILE`` read (nonzero pixels are bad), None without it."""
    if args.mask is None:
        return None
    from .pipeline.masked import load_mask

    try:
        return load_mask(args.mask)
    except (OSError, ValueError) as exc:
        raise CLIError(f"--mask: {_one_line(exc)}") from None


def _load(job: _Job, args: argparse.Namespace,
          body: tuple[Callable[..., Any], dict[str, Any]] | None, mask: Any = None,
          ) -> tuple[Any, float | None, list[Any], Any]:
    """Job ``job``'s files read, as an item of :func:`~dtalign.pipeline.batch.fit_images`
    (called in the image's task), with the ``--sphere`` or ``--ellipsoid`` model's edge
    profile if any, and its bad pixels: ``mask`` (``--mask``), or none but its NaN
    and inf pixels with ``--mask-nonfinite``; what is said or plotted
    afterwards is kept on the job."""
    import numpy as np

    import dtalign.io as io

    masked = mask is not None or args.mask_nonfinite
    image, job.colour = io.read_image(job.image, nonfinite=masked)
    if mask is None and masked:
        mask = np.zeros(image.shape, dtype=bool)  # the NaN and inf pixels only
    poly = io.load_polyline_csv(job.polyline)
    if body is not None:
        build, keywords = body
        poly = dataclasses.replace(poly, edge_profile=build(poly, **keywords))
    job.loaded = (image, poly)
    return image, args.noise_sigma, [poly], mask


def _numbers(text: str, option: str, form: str, counts: tuple[int, ...], how_many: str
             ) -> list[float]:
    """``option``'s comma-separated numbers, as many as one of ``counts``."""
    try:
        values = [float(x) for x in str(text).split(",")]
    except ValueError:
        raise CLIError(f"{option} takes numbers {form}, got {text!r}") from None
    if len(values) not in counts:
        raise CLIError(f"{option} takes {how_many} numbers {form}, got {text!r}")
    return values


_ELLIPSOID_FORM = "V,U,A,B,C,PHASE,LIGHT[,R11,R12,...,R33]"


def _sphere_profile(poly: Any, **keywords: Any) -> Any:
    """:func:`dtalign.sphere_edge_profile` of a polyline (``--sphere``)."""
    from .api.profiles import sphere_edge_profile

    return sphere_edge_profile(poly.vertices_vu, **keywords)


def _ellipsoid_profile(poly: Any, **keywords: Any) -> Any:
    """:func:`dtalign.ellipsoid_edge_profile` of a polyline (``--ellipsoid``)."""
    from .api.ellipsoid import ellipsoid_edge_profile

    return ellipsoid_edge_profile(poly.vertices_vu, **keywords)


def _rendered_profile(poly: Any, *, model_image: Any, **keywords: Any) -> Any:
    """:func:`dtalign.model_image_edge_profile` of a polyline (``--model-render``)."""
    from .api.model_profile import model_image_edge_profile

    return model_image_edge_profile(model_image, poly.vertices_vu, poly.normals_vu, **keywords)


def _body_model(args: argparse.Namespace) -> tuple[Callable[..., Any], dict[str, Any]] | None:
    """``--sphere``, ``--ellipsoid`` or ``--model-render``, with ``--law``, ``--edge`` and
    ``--psf-sigma``: the edge profile's builder (of the polyline) and its keywords
    (None without any)."""
    bodies = [o for o, v in (("--sphere", args.sphere), ("--ellipsoid", args.ellipsoid),
                             ("--model-render", args.model_render)) if v is not None]
    if not bodies:
        for option, given in (("--law", args.law != "lambert"), ("--edge", args.edge != "limb"),
                              ("--psf-sigma", args.psf_sigma is not None)):
            if given:
                raise CLIError(f"{option} needs --sphere, --ellipsoid or --model-render")
        return None
    if len(bodies) > 1:
        raise CLIError(f"{' and '.join(bodies)} exclude each other: the polyline is one body's")
    if args.model_render is not None:
        return _rendered_body(args)
    law, _, k = str(args.law).partition(",")
    minnaert_k: float | None = None
    if law == "minnaert":
        try:
            minnaert_k = float(k)
        except ValueError:
            raise CLIError(f"--law minnaert needs its exponent (minnaert,K), got {args.law!r}") from None
    elif k:
        raise CLIError(f"--law takes lambert, minnaert,K or lommel-seeliger, got {args.law!r}")
    common = {"edge": args.edge, "law": law, "minnaert_k": minnaert_k,
              "psf_sigma_px": args.psf_sigma}
    if args.sphere is not None:
        values = _numbers(args.sphere, "--sphere", "V,U,R,PHASE,LIGHT", (5,), "five")
        return _sphere_profile, {"center_vu": (values[0], values[1]), "radius_px": values[2],
                                 "phase_deg": values[3], "illumination_deg": values[4], **common}
    values = _numbers(args.ellipsoid, "--ellipsoid", _ELLIPSOID_FORM, (7, 16), "7 or 16")
    rotation = [values[7:10], values[10:13], values[13:16]] if len(values) == 16 else None
    return _ellipsoid_profile, {"center_vu": (values[0], values[1]),
                                "axes_px": tuple(values[2:5]), "rotation": rotation,
                                "phase_deg": values[5], "illumination_deg": values[6], **common}


def _rendered_body(args: argparse.Namespace) -> tuple[Callable[..., Any], dict[str, Any]]:
    """``--model-render FILE,K``: the technique's render of the body, read once, at
    ``K`` render pixels per image pixel, and ``--edge`` and ``--psf-sigma``
    (``--law`` is the render's own)."""
    if args.law != "lambert":
        raise CLIError("--law needs --sphere or --ellipsoid: a render carries its own law")
    path, _, k = str(args.model_render).rpartition(",")
    try:
        oversample = int(k)
    except ValueError:
        oversample = 0
    if not path or oversample < 1:
        raise CLIError(f"--model-render takes FILE,K (K render pixels per image pixel, an "
                       f"integer >= 1), got {args.model_render!r}")
    import dtalign.io as io

    try:
        render = io.load_image(path)
    except (OSError, ValueError, TypeError) as exc:
        raise CLIError(f"--model-render {path}: {_one_line(exc)}") from None
    return _rendered_profile, {"model_image": render, "oversample": oversample,
                               "edge": args.edge, "psf_sigma_px": args.psf_sigma}


def _table_single(job: _Job, fit: Any, d: dict[str, Any], estimated: bool) -> str:
    """One fit's report; ``d`` is its ``to_dict()``."""
    from .pipeline.status import UNMEASURED_TEXT

    p, rank, n = fit.n_params, fit.observable_rank, d["n_vertices"]
    lines = [
        f"image        : {job.image}",
        f"polyline     : {job.polyline} ({n} vertices)",
        f"noise sigma  : {fit.noise_sigma:.4g}{_quantised(fit.noise_sigma) if estimated else ''}",
        f"coarse       : (dv, du) = {fit.coarse_offset_vu}, window ±{fit.search_window_vu}",
        _offset_line(fit),
    ]
    if fit.fit_rotation:
        lines.append(f"rotation     : {fit.rotation_rad:.6f} "
                     f"{_sigma_text(fit, fit.sigma_rotation_rad, 6)} rad"
                     f" about {tuple(round(x, 2) for x in fit.pivot_vu)}")
    obs = f"rank {rank} of {p}" + "".join(
        f"; unobservable along {tuple(round(float(x), 4) for x in e)} (sigma inf)"
        for e in fit.unobservable_directions)
    if fit.failed:  # no direction of a failed fit is a measurement: no "inf" to read
        obs = f"rank {rank} of {p}, sigma {UNMEASURED_TEXT}"
    rms = f"{_fmt(fit.lm.rms_px)} px" if math.isfinite(fit.lm.rms_px) else "not measured"
    lines += [
        f"observable   : {obs}",
        f"fit quality  : rms {rms}, inliers {fit.lm.inlier_count}/{n}, "
        f"polarity-rejected {d['polarity_rejected']}, Tukey-rejected {d['tukey_rejected']}",
        f"LM           : {fit.lm.iterations} iterations, {_settled_text(fit)}, "
        f"degenerate={fit.lm.degenerate}",
    ]
    if fit.profile is not None:
        lines.append(_profile_line(fit.profile))
    lines.append(f"status       : {fit.status_message}")
    amb = fit.ambiguity
    if amb is not None:
        rival = (
            "no rival basin across the edge" if amb.rival is None
            else f"best rival basin at ({amb.rival.offset_vu[0]:.2f}, {amb.rival.offset_vu[1]:.2f})"
            f" costs {amb.ratio:.2f}x this fit"
        )
        lines.append(f"ambiguity    : {rival} ({len(fit.hypotheses)} hypotheses; "
                     "ambiguous below 1.5x)")
    t = fit.timings_s
    lines.append("wall time    : " + ", ".join(
        f"{k} {t[k] * 1e3:.1f} ms" for k in ("noise", "derivatives", "fit", "hypotheses", "profile")
        if k in t))
    return "\n".join(lines)


def _profile_line(prof: Any) -> str:
    """The ``profile`` line of a fit's report: the refinement's outcome and fit."""
    return (
        f"profile      : {'accepted' if prof.accepted else 'discarded'}; DT-LM offset "
        f"({prof.dt_offset_vu[0]:.4f}, {prof.dt_offset_vu[1]:.4f}), refined "
        f"({prof.offset_vu[0]:.4f}, {prof.offset_vu[1]:.4f}) after a walk of "
        f"{prof.walk_px:.3f} px; PSF sigma {prof.psf_sigma_px:.3f} px"
        f"{' (estimated)' if prof.psf_estimated else ''}, gain {prof.gain:.4g}, "
        f"{prof.n_pixels} pixels, {prof.iterations} iterations"
    )


def _quantised(sigma: float) -> str:
    """A note after a noise estimate that sits on the quantisation floor of integer pixels."""
    from .pipeline.products import QUANTISED_NOISE_STEP, quantised_noise_steps

    steps = quantised_noise_steps(sigma)
    if steps is None:
        return ""
    return (f" (= {steps:g} x {QUANTISED_NOISE_STEP:.4f}: the MAD of quantised pixels, "
            f"about {round(sigma, 1):g} DN; --noise-sigma if known)")


def _offset_line(fit: Any) -> str:
    """The main line: the offset where the fit observes it, with the rank.

    A rank-deficient fit leads with the offset along each observed direction
    and says which direction is not measured (no finite sigma there).
    """
    (dv, du), (sv, su) = fit.offset_vu, fit.sigma_vu
    if fit.lm.degenerate:
        return f"offset       : none measured (degenerate; the coarse seed is {fit.coarse_offset_vu})"
    if fit.failed:  # where the LM stopped, not a measurement: no sigma
        return (f"offset       : not measured (status failed: see below); the LM stopped at "
                f"({_fmt(dv, 2)}, {_fmt(du, 2)})")
    observed = fit.observable_offset()
    if len(observed) == 2 and math.isfinite(sv) and math.isfinite(su):
        return (f"offset       : dv = {_fmt(dv, 4)} ± {_fmt(sv, 4)}   du = {_fmt(du, 4)} ± "
                f"{_fmt(su, 4)} px (1 sigma)")
    parts = [f"along ({e[0]:.4f}, {e[1]:.4f}): {_fmt(x, 4)} ± {_fmt(sd, 4)} px"
             for e, x, sd in observed]
    # no (dv, du) here: along the unmeasured direction it is the seed's, not a measurement
    return (f"offset       : rank {fit.observable_rank} of {fit.n_params}: " + "; ".join(parts)
            + " (1 sigma); not measured along "
            + " and ".join(f"({float(e[0]) + 0.0:.4f}, {float(e[1]) + 0.0:.4f})"
                           for e in fit.unobservable_directions if abs(e[0]) + abs(e[1]) > 1e-6))


def _table_batch(rows: list[dict[str, Any]]) -> str:
    """A batch's table: one row per image, its fit's numbers or its error."""
    width = max([5, *(len(r["label"]) for r in rows)])
    header = (f"{'image':<{width}} {'dv':>9} {'du':>9} {'sigma_v':>8} {'sigma_u':>8} {'rank':>4} "
              f"{'inliers':>9}  status")
    lines = [header, "-" * len(header)]

    def f(x: Any, d: int) -> str:
        return "inf" if x is None else f"{x:.{d}f}"  # to_dict's None: not finite

    for r in rows:
        name = r["label"]
        if "error" in r:
            lines.append(f"{name:<{width}} {'':>9} {'':>9} {'':>8} {'':>8} {'':>4} {'':>9}  "
                         f"FAILED: {r['error']}")
            continue
        status = r["status"] + (f" ({', '.join(r['reasons'])})" if r["reasons"] else "")
        # a failed fit's pose is not a measurement: no numbers in its row
        (dv, du), (sv, su) = (
            (("-", "-"), ("-", "-")) if r["status"] == "failed"
            else ((f(r["offset_vu"][0], 3), f(r["offset_vu"][1], 3)),
                  (f(r["sigma_vu"][0], 4), f(r["sigma_vu"][1], 4))))
        inliers = f"{r['inlier_count']}/{r['n_vertices']}"
        lines.append(f"{name:<{width}} {dv:>9} {du:>9} {sv:>8} {su:>8} "
                     f"{r['observable_rank']:>4} {inliers:>9}  {status}")
    return "\n".join(lines)


# ---------------------------------------------------------------------------
# overlay and bench
# ---------------------------------------------------------------------------


def _cmd_overlay(args: argparse.Namespace) -> int:
    if args.n_lines < 1:
        raise CLIError(f"--n-lines must be >= 1, got {args.n_lines}")
    displace = _pair_arg(args.displace, "--displace", example="3,-2")  # before any file is written
    _check_output_file(args.image, "--image")
    _check_output_file(args.polyline, "--polyline")

    import numpy as np

    from .io.cassini import load_cassini_overlay_frame, overlay_polylines
    from .io.files import concatenate_polylines, save_polyline_csv

    frame = load_cassini_overlay_frame(args.png)
    lines = overlay_polylines(frame, shape=args.shape, n_lines=args.n_lines)
    model = concatenate_polylines(lines, name=Path(args.png).stem)
    if not all(math.isfinite(x) for x in displace):
        raise CLIError(f"--displace must be finite, got {args.displace!r}")
    moved = dataclasses.replace(model, vertices_vu=model.vertices_vu - np.asarray(displace))
    np.save(args.image, frame.image)
    save_polyline_csv(args.polyline, moved)
    print(
        f"{args.png}: {frame.image.shape[0]} x {frame.image.shape[1]} image "
        f"({frame.header_rows} header rows cropped) -> {args.image}; "
        f"{len(moved)} vertices on {len(lines)} curve(s) -> {args.polyline}"
    )
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    try:
        module = importlib.import_module("dtalign.benchmarking")
    except ModuleNotFoundError as exc:
        if exc.name != "dtalign.benchmarking":
            raise
        return _fail("benchmarks are not available: this build has no dtalign.benchmarking module")
    return int(module.main([a for a in args.args if a != "--"]) or 0)


# ---------------------------------------------------------------------------
# The subcommands' options, the parser and main
# ---------------------------------------------------------------------------

#: One option of a subcommand: its flags (space-separated) and the keywords
#: of ``add_argument``.
_Option = tuple[str, dict[str, Any]]


def _fit_field(dest: str, **spec: Any) -> dict[str, Any]:
    """A ``fit`` flag setting :class:`~dtalign.api.options.FitOptions` field
    ``dest``: absent from the arguments unless given, so that the field's own
    default stands."""
    return dict(dest=dest, default=argparse.SUPPRESS, **spec)


def _plot_options(plot_help: str) -> list[_Option]:
    return [
        ("--plot", dict(metavar="OUT.png", help=plot_help)),
        ("--zoom", dict(action="append", metavar="V,U", help="add a zoomed panel around image "
                        "point (V, U) to the plot (repeatable)")),
        ("--zoom-half", dict(type=float, default=DEFAULT_ZOOM_HALF_PX, metavar="PX",
                             help="half-size of each zoom panel in px "
                             f"(default {DEFAULT_ZOOM_HALF_PX:g})")),
    ]


def _output_options(instead: str, written: str) -> list[_Option]:
    """``--json`` (print JSON instead of ``instead``) and ``-o FILE`` (write ``written`` or JSON)."""
    return [("--json", dict(action="store_true", help=f"print JSON instead of {instead}")),
            ("-o --output", dict(metavar="FILE", help=f"write {written} or JSON to FILE"))]


_WINDOW = ",".join(map(str, DEFAULT_SEARCH_WINDOW_VU))

_DEMO: list[_Option] = [
    ("--seed", dict(type=int, default=0, help="noise seed (default 0)")),
    ("--n-vertices", dict(type=int, default=200, metavar="N", help="limb vertices (default 200)")),
    ("--rotation", dict(type=float, metavar="RAD",
                        help="true rotation in radians; also fits the rotation")),
    ("--window", dict(type=int, default=30, metavar="N", help="search margin in px (default 30)")),
    ("--repeat", dict(type=int, default=1, metavar="N",
                      help="run the stages N times, report the last (default 1)")),
    *_plot_options("write a picture of the fit"),
    *_output_options("text", "the text"),
    ("--save", dict(metavar="DIR", help="write the scene as DIR/demo.npy (image) and "
                    "DIR/demo.csv (polyline) for 'fit'")),
]

_FIT: list[_Option] = [
    ("pairs", dict(nargs="*", metavar="IMAGE POLYLINE", help="image and polyline files")),
    ("--batch", dict(metavar="LIST", help="text file, one 'IMAGE [POLYLINE]' per line "
                     "(POLYLINE defaults to IMAGE's stem + .csv)")),
    ("--glob", dict(metavar="PATTERN", help="images matching PATTERN (quote it)")),
    ("--window", dict(default=_WINDOW, metavar="N|V,U",
                      help="search margin in px: N for both axes, or V,U (e.g. 30,20); "
                      f"default {_WINDOW}, as FitOptions.search_window_vu")),
    ("--noise-sigma", dict(type=float, help="image noise sigma (default: estimated)")),
    ("--mask", dict(metavar="FILE", help="bad-pixel mask for every image (.npy, .png, .fits of "
                    "the image's shape; nonzero = bad): those pixels, and NaN or inf ones, are "
                    "ignored")),
    ("--mask-nonfinite", dict(action="store_true", help="ignore NaN and inf pixels (masked) "
                              "instead of refusing the image")),
    ("--rotation", _fit_field("fit_rotation", action="store_true",
                              help="also fit an in-plane rotation")),
    ("--ridge", _fit_field("final_gradient_ridge", action="store_true",
                           help="finish with the gradient-ridge polish")),
    ("--trust-region", _fit_field("trust_region_px", type=float, metavar="PX",
                                  help="LM trust region (1.0 in production)")),
    ("--tikhonov", _fit_field("tikhonov_alpha", type=float, metavar="ALPHA",
                              help="pull toward the coarse seed")),
    ("--no-polarity", _fit_field("use_polarity", action="store_false",
                                 help="do not reject vertices by polarity")),
    ("--sphere", dict(metavar="V,U,R,PHASE,LIGHT", help="the polyline is a sphere's edge: model "
                      "centre V,U, radius R px, phase and light direction in degrees (0 = up, "
                      "90 = +u); refines the fit with its photometric profile (see the docs' "
                      "profiles page)")),
    ("--ellipsoid", dict(metavar=_ELLIPSOID_FORM, help="the polyline is a triaxial "
                         "ellipsoid's edge: model centre V,U, semi-axes A,B,C px, phase and "
                         "light direction as --sphere's, and optionally the 3 x 3 rotation row "
                         "by row, its columns the axes' directions in (v, u, toward the viewer) "
                         "(default: the identity); refines the fit with its photometric "
                         "profile")),
    ("--model-render", dict(metavar="FILE,K", help="the polyline's edge profile sampled "
                            "from the technique's own render of the body (.npy, .fits, .png), "
                            "sharp, K render pixels per image pixel, tiling the frame from its "
                            "pixel (0, 0) (dtalign.model_image_edge_profile); refines the fit "
                            "with it")),
    ("--law", dict(default="lambert", metavar="LAW",
                   help="with --sphere or --ellipsoid: lambert (default), minnaert,K or "
                   "lommel-seeliger")),
    ("--edge", dict(choices=("limb", "terminator"), default="limb",
                    help="with --sphere or --ellipsoid: which edge the polyline is "
                    "(default limb)")),
    ("--psf-sigma", dict(type=float, metavar="PX",
                         help="with --sphere or --ellipsoid: the PSF's Gaussian sigma "
                         "(default: estimated)")),
    # the choices are dtalign.api.profiles.EDGE_KINDS (tests/test_terminator.py checks)
    ("--edge-kind", _fit_field("edge_kind", choices=("limb", "terminator", "ring", "other"),
                               help="what kind of edge the polyline is (with --sphere or "
                               "--ellipsoid: --edge's); a terminator without either is "
                               "reported suspect")),
    *_output_options("a table", "the table"),
    *_plot_options("write a picture of the fit (with several images: OUT_<image label>.png)"),
    ("--no-progress", dict(action="store_true", help="no progress bar")),
]

_OVERLAY: list[_Option] = [
    ("png", dict(metavar="PNG", help="the summary PNG")),
    ("--shape", dict(choices=("limb", "lines"), required=True, help="what the overlay is")),
    ("--n-lines", dict(type=int, default=2, metavar="N", help="straight lines to trace (default 2)")),
    ("--image", dict(required=True, metavar="OUT.npy", help="write the grey image here")),
    ("--polyline", dict(required=True, metavar="OUT.csv", help="write the polyline here")),
    ("--displace", dict(default="0,0", metavar="DV,DU", help="move the model by -(DV, DU), e.g. "
                        "--displace 3,-2: a correct fit then returns about (DV, DU)")),
]

#: Each subcommand (``archive`` aside: :mod:`dtalign.archive.cli`): its handler,
#: its one-line help, its description and its options, in their help order.
_COMMANDS: dict[str, tuple[Callable[[argparse.Namespace], int], str, str, list[_Option]]] = {
    "demo": (_cmd_demo, "fit the synthetic disc scene and time each stage",
             "Build the seeded disc scene (a bright disc with a displaced limb polyline), run "
             "derivatives, coarse search and LM, and print the truth, the fit and the stage "
             "times.", _DEMO),
    "fit": (_cmd_fit, "fit model polylines (CSV v,u,nv,nu,sigma) to images",
            "Fit each IMAGE (.npy, .png, .fits) with its POLYLINE CSV (header v,u,nv,nu,sigma; "
            "the normal (nv, nu) points to the bright side of the edge). Give IMAGE POLYLINE "
            "pairs, or --batch/--glob for many images whose polyline is the .csv of the same "
            "stem. Options may come anywhere.", _FIT),
    "overlay": (_cmd_overlay, "split a Cassini summary PNG into an image and a model polyline CSV",
                "Read a summary PNG (grey image + red model overlay), write the clean grey image "
                "(.npy) and the traced overlay as a polyline CSV, optionally displaced.", _OVERLAY),
    # every argument after "bench" is the benchmark module's, --help too
    "bench": (_cmd_bench, "quick benchmark table",
              "Run dtalign.benchmarking (options are passed through).",
              [("args", dict(nargs=argparse.REMAINDER))]),
}

#: Options that take a pair of numbers, per subcommand: those whose metavar
#: is two names joined by a comma, the one style everywhere (``--displace 3,-2``).
PAIR_OPTIONS = {name: frozenset(flags for flags, spec in options
                                if str(spec.get("metavar", "")).count(",") == 1)
                for name, (_, _, _, options) in _COMMANDS.items()}


def _build() -> tuple[argparse.ArgumentParser, dict[str, argparse.ArgumentParser]]:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Align a model polyline against an image's edge distance transform.",
    )
    parser.add_argument("--version", action="store_true", help="print the version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (handler, help_, description, options) in _COMMANDS.items():
        p = sub.add_parser(name, help=help_, description=description, add_help=name != "bench")
        p.set_defaults(handler=handler)
        for flags, spec in options:
            p.add_argument(*flags.split(), **spec)
    from .archive import cli as archive_cli

    archive_cli.add_parser(sub).set_defaults(handler=archive_cli.command)
    return parser, dict(sub.choices)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``dtalign`` command."""
    return _build()[0]


def _pairs_joined(command: str, argv: list[str], parser: argparse.ArgumentParser) -> list[str]:
    """``argv`` with each pair option's value attached (``--displace=-2,3``), or a usage error.

    Attaching the value lets it start with a minus sign, which argparse
    would otherwise read as an option. Two numbers given as two words
    (``--window 30 20``) are refused with the form to use, instead of
    argparse's or the file pairing's own, misleading, error.
    """
    options, out, i = PAIR_OPTIONS.get(command, frozenset()), [], 0
    while i < len(argv):
        word, (value, after) = argv[i], (argv[i + 1 : i + 3] + [None, None])[:2]
        if word in options and value is not None and not value.startswith("--"):
            if (_NUMBER.fullmatch(value) and after is not None and _NUMBER.fullmatch(after)
                    and not os.path.exists(after)):
                parser.error(
                    f"{word} takes its two numbers as one word, joined by a comma: "
                    f"write {word} {value},{after}, not {word} {value} {after}"
                )
            out.append(f"{word}={value}")
            i += 2
        else:
            out.append(word)
            i += 1
    return out


def _parse(argv: list[str]) -> argparse.Namespace | int:
    """The parsed arguments, or an exit status (help, version, usage error).

    The top-level parser takes the options before the subcommand; the
    subcommand's own parser then reads the rest intermixed, so options may
    follow or separate the file names, which argparse's subparsers alone
    do not allow.
    """
    parser, commands = _build()
    where = next((i for i, a in enumerate(argv) if not a.startswith("-")), None)
    try:
        if where is None or argv[where] not in commands:
            args = parser.parse_args(argv)  # help, version, or argparse's own error
        else:
            args = parser.parse_args(argv[:where])
            if not args.version:
                command = commands[argv[where]]
                rest = _pairs_joined(argv[where], argv[where + 1 :], command)
                args = command.parse_intermixed_args(rest)
                args.command, args.version = argv[where], False
    except SystemExit as exc:  # argparse printed help or its usage error
        return int(exc.code or 0)
    if args.version:
        from ._version import __version__

        print(f"{PROG} {__version__}")
        return 0
    if getattr(args, "command", None) is None:
        parser.print_help()
        return 2
    return args


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``dtalign`` command line; returns the exit status.

    Parameters
    ----------
    argv : sequence of str, optional
        Arguments without the program name; ``sys.argv[1:]`` when None.

    Returns
    -------
    int
        0 on success; 1 on an error or a failed image; 2 for a malformed
        command line; 3 (:data:`EXIT_FIT_FAILED`) or 4
        (:data:`EXIT_FIT_DOUBTFUL`) for a failed or doubtful fit; 130 when
        interrupted (:doc:`/cli` has the table).
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        if argv[:1] == ["bench"]:
            # Everything after "bench" belongs to the benchmark module, options too.
            return _cmd_bench(argparse.Namespace(args=argv[1:]))
        args = _parse(argv)
        if isinstance(args, int):
            return args
        log = logging.getLogger("dtalign")
        log.addHandler(_WARNINGS)
        _MESSAGES.bar = None
        _WARNINGS.label = args.command if args.command == "demo" else ""
        try:
            return int(args.handler(args))
        except (CLIError, OSError, ValueError, TypeError, ImportError) as exc:
            if os.environ.get("DTALIGN_DEBUG") and not isinstance(exc, CLIError):
                raise
            return _fail(_one_line(exc))
        finally:
            log.removeHandler(_WARNINGS)
    except KeyboardInterrupt:
        print(f"\n{PROG}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
