"""The campaign manifest: which images to fit, with which polylines and options.

A manifest is a text file with one **item** (one image) per record, in one
of two formats chosen by the file's suffix:

* **JSON lines** (``.jsonl``, ``.ndjson``): one JSON object per line::

    {"image": "frames/f000.npy", "polylines": ["frames/f000-limb.csv", "frames/f000-ring.csv"],
     "noise_sigma": 2.0, "window": [30, 20], "options": {"trust_region_px": 1.0}}

* **CSV** (``.csv``): a header row naming the same fields; ``polylines``
  holds one or more paths separated by ``;``, ``window`` one int or two
  separated by a space, ``options`` a JSON object::

    id,image,polylines,noise_sigma,window,options
    f000,frames/f000.npy,frames/f000-limb.csv;frames/f000-ring.csv,2.0,30 20,"{""trust_region_px"": 1.0}"

Fields (only ``image`` and ``polylines`` are required):

``id``
    The item's name in the results store, unique in the manifest; the
    ``image`` path as written when absent.
``image``
    The image file (anything :func:`dtalign.io.load_image` reads).
``polylines``
    One polyline CSV path, or a list of them
    (:func:`dtalign.io.load_polyline_csv`). Each is fitted separately
    against the image's products and gives one row of results.
``noise_sigma``
    The image noise sigma; estimated from the image when absent or null.
``window``
    Coarse-search margin: an int for both axes or ``[mv, mu]`` (in a CSV
    cell ``30`` or ``30 20``); the campaign's default (30) when absent.
``options``
    Keyword options of :func:`dtalign.pipeline.fit_polyline_products`
    (``fit_rotation``, ``trust_region_px``, ``use_polarity``, ...), over
    the campaign's defaults.
``config``
    Fields of :class:`dtalign.ImageDerivativesConfig` for this image.
``spheres``
    Optional, one entry per polyline: null, or the sphere whose edge the
    polyline is, as the keywords of :func:`dtalign.sphere_edge_profile`
    (``center_vu``, ``radius_px``, ``phase_deg``, ``illumination_deg``
    required; ``edge``, ``law``, ``minnaert_k``, ``psf_sigma_px``
    optional): the fit is then refined with its photometric profile
    (:ref:`profiles`). In a CSV manifest, a JSON list in the cell.
``mask``
    Optional: a bad-pixel mask file of the image's shape (anything
    :func:`dtalign.io.load_image` reads; nonzero = bad). Those pixels, and
    the image's NaN or inf ones, are ignored
    (:func:`dtalign.pipeline.prepare_image`'s ``mask``, :ref:`robustness-masks`).
``mask_nonfinite``
    Optional, ``true`` or ``false`` (default): without a ``mask``, ignore
    the image's NaN and inf pixels instead of failing the item.

Relative paths are relative to the manifest's folder. Blank lines, and
lines starting with ``#``, are skipped. Reading checks the structure of
every record (types, unknown fields and options, duplicate ids) and names
the line of the first bad one; whether the files exist and the values fit
is found out when the item runs, and a bad item goes to the store's
failures table without stopping the campaign.

This module imports neither Dask nor pyarrow.
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..api import checks as check

__all__ = ["DEFAULT_WINDOW", "FIELDS", "Item", "read_manifest", "write_manifest"]

PathLike = str | os.PathLike[str]

#: The coarse-search margin of an item that gives none: the CLI's default.
DEFAULT_WINDOW = (30, 30)

#: The fields a manifest record may have.
FIELDS = ("id", "image", "polylines", "noise_sigma", "window", "options", "config", "spheres",
          "mask", "mask_nonfinite")

#: Keys of a ``spheres`` entry: the keywords of :func:`dtalign.sphere_edge_profile`.
SPHERE_KEYS = ("center_vu", "radius_px", "phase_deg", "illumination_deg", "edge", "law",
               "minnaert_k", "psf_sigma_px")
_SPHERE_REQUIRED = ("center_vu", "radius_px", "phase_deg", "illumination_deg")

#: Suffixes read as JSON lines; ``.csv`` is read as CSV.
_JSONL_SUFFIXES = (".jsonl", ".ndjson", ".json")

#: Separator of several polyline paths in one CSV cell (``,`` is the column separator).
CSV_POLYLINE_SEPARATOR = ";"

#: The ImageDerivativesConfig fields a record's ``config`` may set.
_CONFIG_FIELDS = ("image_gradient_sigma_px", "edge_threshold_k_sigma", "dt_half_width_px")


def fit_option_names() -> frozenset[str]:
    """The fields of :class:`dtalign.FitOptions` a record's ``options`` may set (not
    the edge profile: a polyline's comes from the item's ``spheres``)."""
    from ..api.options import NAMES

    return NAMES - {"edge_profile"}


@dataclass(frozen=True)
class Item:
    """One image of a campaign and what to fit on it.

    Attributes
    ----------
    id : str
        Unique name of the item in the store.
    image : str
        The image path as the manifest writes it.
    polylines : tuple of str
        The polyline CSV paths as the manifest writes them.
    image_path : str
        ``image`` resolved against the manifest's folder (what a worker reads).
    polyline_paths : tuple of str
        ``polylines`` resolved likewise.
    noise_sigma : float or None
        The noise sigma, None to estimate it.
    window : tuple of int
        The coarse-search margin ``(mv, mu)``.
    options : dict
        Fit options (campaign defaults merged with the item's own).
    config : dict
        :class:`~dtalign.ImageDerivativesConfig` fields (empty: defaults).
    spheres : tuple of (dict or None)
        Per polyline, the sphere model whose photometric profile refines its
        fit (the keywords of :func:`dtalign.sphere_edge_profile`), or None;
        empty when the manifest gives none.
    line : int
        The manifest line the item came from (for messages).
    mask : str or None
        The bad-pixel mask file as the manifest writes it; None without one.
    mask_path : str or None
        ``mask`` resolved against the manifest's folder.
    mask_nonfinite : bool
        Whether the image's NaN and inf pixels are masked (always, with a ``mask``).
    """

    id: str
    image: str
    polylines: tuple[str, ...]
    image_path: str
    polyline_paths: tuple[str, ...]
    noise_sigma: float | None = None
    window: tuple[int, int] = DEFAULT_WINDOW
    options: dict[str, Any] = field(default_factory=dict)
    config: dict[str, float] = field(default_factory=dict)
    line: int = 0
    spheres: tuple[dict[str, Any] | None, ...] = ()
    mask: str | None = None
    mask_path: str | None = None
    mask_nonfinite: bool = False

    @property
    def fingerprint(self) -> str:
        """A short hash of what the item asks for (files, noise, window, options).

        The store records it with each result, so a re-run can tell that an
        item id now means something else.
        """
        fields: list[Any] = [self.image, list(self.polylines), self.noise_sigma,
                             list(self.window), sorted(self.options.items()),
                             sorted(self.config.items())]
        if self.spheres:  # an item without spheres keeps the fingerprint it always had
            fields.append(list(self.spheres))
        if self.mask is not None or self.mask_nonfinite:  # likewise an item without a mask
            fields.append(["mask", self.mask, self.mask_nonfinite])
        payload = json.dumps(fields, sort_keys=True, default=repr)
        return hashlib.sha256(payload.encode()).hexdigest()[:16]

    def to_record(self) -> dict[str, Any]:
        """The item as a manifest record (the paths as written)."""
        rec: dict[str, Any] = {"id": self.id, "image": self.image, "polylines": list(self.polylines)}
        if self.noise_sigma is not None:
            rec["noise_sigma"] = self.noise_sigma
        rec["window"] = list(self.window)
        if self.options:
            rec["options"] = dict(self.options)
        if self.config:
            rec["config"] = dict(self.config)
        if self.spheres:
            rec["spheres"] = list(self.spheres)
        if self.mask is not None:
            rec["mask"] = self.mask
        if self.mask_nonfinite:
            rec["mask_nonfinite"] = True
        return rec


def _where(path: Path, line: int) -> str:
    return f"manifest {path} line {line}"


def _spheres(value: Any, n: int, where: str) -> tuple[dict[str, Any] | None, ...]:
    """``spheres``: a list (JSON text in a CSV cell) of one sphere model or null per polyline."""
    entries = check.json_list(value, n, f"{where}: spheres", "polyline")
    return tuple(
        None if entry is None
        else check.keywords(entry, f"{where}: spheres[{k}]", SPHERE_KEYS, _SPHERE_REQUIRED)
        for k, entry in enumerate(entries)
    )


def _resolve(base: Path, p: str) -> str:
    path = Path(p).expanduser()
    return str(path if path.is_absolute() else base / path)


def _item(
    record: Any, base: Path, where: str, line: int, defaults: Mapping[str, Any],
    option_names: frozenset[str],
) -> Item:
    if not isinstance(record, Mapping):
        raise ValueError(f"{where}: a record must be an object, got {type(record).__name__}")
    check.known_names(record, FIELDS, "field", where)
    image = check.path_text(record.get("image"), f"{where}: image")
    polylines = check.path_list(record.get("polylines"), f"{where}: polylines",
                                CSV_POLYLINE_SEPARATOR)
    item_id = check.label(record.get("id"), f"{where}: id", default=image)
    options = {**defaults.get("options", {}),
               **check.json_object(record.get("options"), f"{where}: options")}
    check.known_names(options, sorted(option_names), "fit option", where)
    config = check.json_object(record.get("config"), f"{where}: config")
    check.known_names(config, _CONFIG_FIELDS, "config field", where)
    window = record.get("window")
    mask = None if check.blank(record.get("mask")) else check.path_text(record.get("mask"),
                                                                        f"{where}: mask")
    return Item(
        id=item_id,
        image=image,
        polylines=polylines,
        image_path=_resolve(base, image),
        polyline_paths=tuple(_resolve(base, p) for p in polylines),
        noise_sigma=check.optional_nonnegative(record.get("noise_sigma"), f"{where}: noise_sigma"),
        window=(defaults.get("window", DEFAULT_WINDOW) if check.blank(window)
                else check.search_window(window, f"{where}: window", form="field")),
        options=options,
        config=config,
        line=line,
        spheres=_spheres(record.get("spheres"), len(polylines), where),
        mask=mask,
        mask_path=None if mask is None else _resolve(base, mask),
        mask_nonfinite=check.flag(record.get("mask_nonfinite"), f"{where}: mask_nonfinite"),
    )


def _records(path: Path) -> Iterable[tuple[int, Any]]:
    suffix = path.suffix.lower()
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"cannot read manifest {path}: {exc}") from None
    if suffix in _JSONL_SUFFIXES:
        for number, line in enumerate(text.splitlines(), 1):
            if not line.strip() or line.lstrip().startswith("#"):
                continue
            try:
                yield number, json.loads(line)
            except json.JSONDecodeError as exc:
                raise ValueError(f"{_where(path, number)}: not JSON: {exc.msg}") from None
    elif suffix == ".csv":
        lines = [
            (n, ln) for n, ln in enumerate(text.splitlines(), 1)
            if ln.strip() and not ln.lstrip().startswith("#")
        ]
        if not lines:
            raise ValueError(f"manifest {path} is empty: need a header with image,polylines")
        rows = list(csv.reader([ln for _, ln in lines]))
        header = [c.strip().lower() for c in rows[0]]
        for (number, _), row in zip(lines[1:], rows[1:], strict=True):
            if len(row) > len(header):
                raise ValueError(
                    f"{_where(path, number)}: {len(row)} cells, but the header has {len(header)}"
                )
            yield number, {h: c for h, c in zip(header, row, strict=False) if c.strip() != ""}
    else:
        raise ValueError(
            f"manifest {path}: unknown format {suffix or '(no suffix)'!r}; "
            "use .jsonl (JSON lines) or .csv"
        )


def read_manifest(
    path: PathLike, *, window: Any = None, options: Mapping[str, Any] | None = None
) -> list[Item]:
    """Read and check a campaign manifest.

    Parameters
    ----------
    path : str or path-like
        A ``.jsonl`` / ``.ndjson`` (JSON lines) or ``.csv`` manifest (see
        the module documentation for the fields).
    window : int, tuple of int or str, optional
        Default coarse-search margin of items that give none (30), in any
        form the ``window`` field takes (``dtalign.api.checks.search_window``).
    options : dict, optional
        Default fit options; an item's own ``options`` override them.

    Returns
    -------
    list of Item
        In manifest order.

    Raises
    ------
    FileNotFoundError
        If the manifest does not exist.
    ValueError
        On a malformed record (the message names the manifest and line), a
        duplicate id, an unknown fit option, or an empty manifest.
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"manifest not found: {p}")
    names = fit_option_names()
    defaults: dict[str, Any] = {}
    if window is not None:
        defaults["window"] = check.search_window(window, "window", form="field")
    if options:
        check.known_names(options, sorted(names), "fit option")
        defaults["options"] = dict(options)
    base = p.resolve().parent
    items: list[Item] = []
    seen: dict[str, int] = {}
    for number, record in _records(p):
        item = _item(record, base, _where(p, number), number, defaults, names)
        if item.id in seen:
            raise ValueError(
                f"{_where(p, number)}: duplicate id {item.id!r} (first on line {seen[item.id]})"
            )
        seen[item.id] = number
        items.append(item)
    if not items:
        raise ValueError(f"manifest {p} has no items")
    return items


def write_manifest(path: PathLike, records: Sequence[Mapping[str, Any]]) -> Path:
    """Write records (dicts with the manifest fields) as a JSON-lines manifest.

    Returns
    -------
    pathlib.Path
        The path written.
    """
    p = Path(path)
    with open(p, "w", encoding="utf-8") as fh:
        for rec in records:
            check.known_names(rec, FIELDS, "manifest field")
            fh.write(json.dumps(dict(rec)) + "\n")
    return p
