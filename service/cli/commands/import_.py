"""``servowatch import``: a recording of one's own (TDMS, MDF 3/4, Parquet, CSV) through a
channel map into an ordinary servowatch log (docs/import.md; the work is in
``service.importer``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from service.cli.util import check_outputs, emit_json, fail, finite_float, writing

NAME = "import"
HELP = "import recordings (TDMS, MDF, Parquet, CSV) through a channel map into servowatch logs"

__all__ = ["NAME", "HELP", "add_arguments", "run"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("files", nargs="+", metavar="FILE", help="recordings to import")
    p.add_argument("--map", required=True, metavar="MAP.toml", help="the channel map (TOML)")
    p.add_argument(
        "--out",
        required=True,
        metavar="OUT",
        help="the log (OUT.mcap, one FILE) or a folder (a log FILE-stem.mcap per FILE)",
    )
    p.add_argument(
        "--start-unix",
        type=finite_float,
        default=None,
        help="calendar time [Unix s] of a relative time axis' zero (else the map's, the file's)",
    )
    p.add_argument("--flight", type=int, default=None, help="flight number (else the map's)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def _targets(args: argparse.Namespace) -> list[tuple[Path, Path]] | str:
    files = [Path(f) for f in args.files]
    out = Path(args.out)
    if out.suffix.lower() == ".mcap":
        if len(files) > 1:
            return f"--out {out}: {len(files)} files need a folder (a log per file)"
        return [(files[0], out)]
    stems = [f.stem for f in files]
    dup = next((s for s in stems if stems.count(s) > 1), None)
    if dup is not None:
        return f"--out {out}: two files named {dup}.* would make one log {dup}.mcap"
    return [(f, out / f"{f.stem}.mcap") for f in files]


def run(args: argparse.Namespace) -> int:
    from service.importer import InputError, import_file, load_map

    if args.flight is not None and not 0 <= args.flight <= 2**31 - 1:
        return fail(f"--flight {args.flight}: an integer in 0..{2**31 - 1}")
    targets = _targets(args)
    if isinstance(targets, str):
        return fail(targets)
    try:
        cmap, raw = load_map(args.map)
    except InputError as e:
        return fail(str(e))
    check_outputs(
        [("--out", o) for _, o in targets],
        [("FILE", f) for f, _ in targets] + [("--map", args.map)],
        makes_folders=("--out",),
    )
    results = []
    for f, o in targets:
        try:
            with writing("--out", o, so_far="nothing of this file was kept"):
                res = import_file(f, cmap, raw, o, start_unix=args.start_unix, flight=args.flight)
        except InputError as e:
            done = f" ({len(results)} file(s) imported before it)" if results else ""
            return fail(f"{e}{done}")
        results.append(res)
        if not args.json:
            if res.status == "unchanged":
                print(f"{f}: already imported as {o} (unchanged)")
            else:
                c = res.counts
                print(f"{f} -> {o}: {res.samples} samples of {', '.join(res.channels)} "
                      f"over {res.duration_s:.3f} s at {c['rate_hz']:g} Hz (copied "
                      f"{c['copied']}, downsampled {c['downsampled']}, interpolated "
                      f"{c['interpolated']}, gaps {c['gaps']}, refused {c['intake'] or 'none'})")  # fmt: skip
    if args.json:
        from dataclasses import asdict

        emit_json({"imports": [asdict(r) for r in results]})
    return 0
