"""``dtalign archive``: the campaign subcommand (its parser and its command).

:mod:`dtalign.cli` adds this parser to its subcommands and calls
:func:`command`; nothing here imports Dask until a run starts.

Exit status, as ``dtalign fit``'s: 0 when every item is done and no fit
failed, 1 when an item is failed (listed in the store's failures table),
3 when every item is done but the status of some fit is ``failed`` (the
store's ``status`` column), 130 after Ctrl-C (what had finished is in the
store: run the same command again to resume).
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

__all__ = ["add_parser", "command"]

#: The exit status after Ctrl-C (128 + SIGINT), as shells report it.
EXIT_INTERRUPTED = 130

#: Every item done, some fit's status ``failed``: ``dtalign fit``'s code for it
#: (dtalign.cli.EXIT_FIT_FAILED; not imported, dtalign.cli imports this module).
EXIT_FIT_FAILED = 3


def add_parser(sub: Any) -> argparse.ArgumentParser:
    """Add the ``archive`` subcommand to ``sub`` (an argparse subparsers object)."""
    p = sub.add_parser(
        "archive",
        help="fit a campaign of images on Dask into a resumable Parquet store",
        description="Fit every item of MANIFEST (JSON lines or CSV: image, polylines, "
        "noise sigma, window, options) on a Dask cluster and append the results to the "
        "Parquet store STORE as they arrive. Items already in the store are skipped, so "
        "running the same command again resumes. Without --scheduler a LocalCluster of "
        "--workers processes is started.",
    )
    p.add_argument("manifest", nargs="?", metavar="MANIFEST", help="the campaign manifest")
    p.add_argument("--out", metavar="STORE", help="the results store (a folder)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="connect to this Dask scheduler")
    p.add_argument("--workers", type=int, metavar="N",
                   help="worker processes of the local cluster (default: one per CPU)")
    p.add_argument("--retry-failed", action="store_true", help="also redo the failed items")
    p.add_argument("--window", metavar="V[,U]",
                   help="default search margin for items without one: 30, or 30,20")
    p.add_argument("--flush-every", type=int, default=None, metavar="ITEMS",
                   help="write a store part every ITEMS items (default 32)")
    p.add_argument("--items-per-task", type=int, default=None, metavar="N",
                   help="items one task fits (default 4, fewer when the campaign is short "
                        "for its workers: Dask costs milliseconds per task; 1 for big frames)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--make-example", metavar="DIR",
                   help="write a synthetic campaign (frames, polylines, DIR/manifest.jsonl) "
                        "and exit")
    p.add_argument("--frames", type=int, default=8, help="frames of --make-example (default 8)")
    p.add_argument("--broken", action="store_true",
                   help="--make-example: also list a missing and a corrupt image")
    return p


def command(args: argparse.Namespace) -> int:
    """Run ``dtalign archive``; returns the exit status.

    Raises
    ------
    ValueError
        On a malformed command line or manifest (the caller prints it as one line).
    """
    from ..api import checks as check
    from . import make_example, run
    from .store import Store

    if args.make_example:
        manifest = make_example(args.make_example, frames=args.frames, broken=args.broken)
        print(f"wrote {manifest}; run it with:\n"
              f"  dtalign archive {manifest} --out {manifest.parent / 'store'}")
        return 0
    if not args.manifest or not args.out:
        raise ValueError("archive needs MANIFEST and --out STORE (or --make-example DIR)")
    window = None
    if args.window is not None:
        window = check.search_window(args.window, "--window", form="field")
    if args.scheduler and args.workers is not None:
        raise ValueError("--workers starts a local cluster; with --scheduler the cluster's "
                         "own workers are used")
    extra: dict[str, Any] = {}
    if args.flush_every is not None:
        extra["flush_items"] = args.flush_every
    if args.items_per_task is not None:
        extra["items_per_task"] = args.items_per_task
    try:
        summary = run(
            args.manifest, args.out, scheduler=args.scheduler, workers=args.workers,
            window=window, retry_failed=args.retry_failed,
            progress=not args.no_progress, **extra,
        )
    except KeyboardInterrupt:
        print(f"dtalign: interrupted; what had finished is in {args.out}: run the same "
              "command again to resume", file=sys.stderr)
        return EXIT_INTERRUPTED
    print(summary)
    store = Store(args.out)
    table = store.failures(["item_id", "error"])
    # The last attempt's error of each item still failed.
    latest = dict(zip(table["item_id"].to_pylist(), table["error"].to_pylist(), strict=True))
    for item_id, error in latest.items():
        print(f"dtalign: FAILED {item_id}: {error}", file=sys.stderr)
    if latest:
        print(f"dtalign: {len(latest)} item(s) failed (the store's failures table)",
              file=sys.stderr)
        return 1
    failed_fits = store.results(["status"])["status"].to_pylist().count("failed")
    if failed_fits:
        print(f"dtalign: {failed_fits} fit(s) in {args.out} have status failed "
              "(the status and reasons columns say why)", file=sys.stderr)
        return EXIT_FIT_FAILED
    return 0
