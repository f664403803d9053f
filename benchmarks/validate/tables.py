"""Summaries of the fit records: one row per family, edge and method.

Columns: ``n`` fits; ``raised`` (exceptions); the median, 95th percentile and
largest error (px) over the fits that returned; ``accepted``, the fraction
whose profile refinement was accepted (profile fits); ``ok``, the fraction
with status ``ok``; ``cov95``, the fraction of the ``ok`` fits inside the
95 % ellipse of the pipeline's covariance (``d2 <= 5.991``); ``wrong``, the
count of confidently wrong fits (``ok`` and ``d2 > 13.8155``, the 99.9 %
ellipse, or more than 1 px off).
"""

from __future__ import annotations

import numpy as np

from .fitting import CHI2_95, METHODS, confidently_wrong

COLUMNS = ("family", "edge", "method", "n", "raised", "median", "p95", "max", "accepted",
           "ok", "cov95", "wrong")


def summarise(records: list[dict]) -> list[dict]:
    """One row per (family, edge, method) present in the records, in their order."""
    keys: list[tuple[str, str, str]] = []
    for r in records:
        k = (r["family"], r["edge"], r["method"])
        if k not in keys:
            keys.append(k)
    keys.sort(key=lambda k: (k[0], k[1], METHODS.index(k[2])))
    rows = []
    for fam, edge, method in keys:
        group = [r for r in records if (r["family"], r["edge"], r["method"]) == (fam, edge, method)]
        done = [r for r in group if r.get("exception") is None]
        err = np.array([r["error_px"] for r in done])
        ok = [r for r in done if r["status"] == "ok"]
        acc = [r["accepted"] for r in done if r.get("accepted") is not None]
        rows.append(dict(
            family=fam, edge=edge, method=method, n=len(group), raised=len(group) - len(done),
            median=float(np.median(err)) if err.size else float("nan"),
            p95=float(np.percentile(err, 95)) if err.size else float("nan"),
            max=float(err.max()) if err.size else float("nan"),
            accepted=float(np.mean(acc)) if acc else float("nan"),
            ok=len(ok) / len(done) if done else float("nan"),
            cov95=float(np.mean([r["d2"] <= CHI2_95 for r in ok])) if ok else float("nan"),
            wrong=sum(confidently_wrong(r) for r in done),
        ))
    return rows


FRACTIONS = ("accepted", "ok", "cov95")


def _cell(column: str, value) -> str:
    if not isinstance(value, float):
        return str(value)
    if np.isnan(value):
        return "-"
    return f"{value:.2f}" if column in FRACTIONS else f"{value:.4f}" if value < 1 else f"{value:.3g}"


def rst_table(rows: list[dict]) -> str:
    """The rows as an RST simple table (also readable as plain text)."""
    cells = [list(COLUMNS)] + [[_cell(c, r[c]) for c in COLUMNS] for r in rows]
    widths = [max(len(row[i]) for row in cells) for i in range(len(COLUMNS))]
    rule = "  ".join("=" * w for w in widths)
    lines = [rule, "  ".join(c.ljust(w) for c, w in zip(cells[0], widths, strict=True)), rule]
    lines += ["  ".join(c.rjust(w) if i >= 3 else c.ljust(w)
                        for i, (c, w) in enumerate(zip(row, widths, strict=True)))
              for row in cells[1:]]
    lines.append(rule)
    return "\n".join(lines)
