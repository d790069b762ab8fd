"""``jaxhyst identify-many``: many independent identifications from a manifest, on a
local Dask cluster, any cluster, or serially (`jaxhyst.batch`)."""

from __future__ import annotations

from .options import POSITIVE_INT
from .spec import CLIError, note


def add_parser(sub) -> None:
    """Register the command and its options on the subparsers ``sub``."""
    parser = sub.add_parser(
        "identify-many", help="many identifications from a manifest (Dask or serial)",
        description="Run 'jaxhyst identify' on every item of a manifest — a CSV with a "
        "'data' column (a file or a glob) and identify's options as further columns, a "
        "TOML file of [[item]] tables or a JSON list of objects (.json) — on a local Dask "
        "cluster (one process per core; "
        "pip install -e '.[cluster]'), a cluster (--scheduler ADDRESS) or serially "
        "(--scheduler serial, or without Dask). Writes OUT/results.csv (one row per item, "
        "rewritten after each; a second run skips the items in it) and each item's "
        "result and model under OUT/items/. Exit 3 if an item failed or stopped short.")
    parser.add_argument("manifest", help="CSV, TOML or JSON manifest")
    parser.add_argument("--out", required=True, help="output folder (results.csv, items/)")
    parser.add_argument("--scheduler", help="a Dask scheduler's address (tcp://HOST:8786), "
                        "'local' (default with Dask) or 'serial'")
    parser.add_argument("--workers", type=POSITIVE_INT,
                        help="processes of the local cluster (default: the cores)")
    parser.add_argument("--quiet", action="store_true", help="no line per item")
    parser.set_defaults(func=run)


def run(args) -> int:
    import os

    from jaxhyst._interrupt import stop_requested
    from jaxhyst.batch import ManifestError, fit_many

    if os.path.exists(args.out) and not os.path.isdir(args.out):
        raise CLIError(f"--out {args.out}: exists and is not a folder.")
    try:
        rows = fit_many(args.manifest, args.out, scheduler=args.scheduler,
                        workers=args.workers,
                        progress=None if args.quiet else lambda line: note("batch", line))
    except ManifestError as err:
        raise CLIError(str(err)) from None
    failed = [r["id"] for r in rows if str(r.get("status")) not in ("0", "4")]
    print(f"{len(rows)} items in {os.path.join(args.out, 'results.csv')}"
          + (f"; not successful: {', '.join(failed)}" if failed else ""))
    if stop_requested():
        return 130
    return 3 if failed else 0
