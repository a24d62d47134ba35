"""Machine-readable benchmark results: one JSON file per (benchmark, dataset).

Every benchmark script records its current figures with :func:`record`; the
file ``benchmarks/results/<bench>/<dataset>.json`` is replaced as a whole, so
it always holds the figures of the last run of that benchmark on that
dataset.  ``benchmarks/RESULTS.md`` is generated from these files.

A row is a dict with the keys ``method`` (what was measured: ``"rooftrace"``,
``"rooftrace --alpha point"``, ``"shapely.concave_hull"``, ...), ``metric``
(``"polis_mean"``, ``"f_score"``, ``"time_s"``, ...), ``value`` (a number),
and optionally ``unit`` (``"m"``, ``"s"``, ``""``) and ``target`` (a string
such as ``"<= 0.10"``; None when the metric has no target).
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import shlex
import sys
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"

__all__ = ["record", "load_all", "RESULTS"]


def record(bench: str, dataset: str, rows: list[dict], *, command: str | None = None) -> Path:
    """Write the rows of one benchmark on one dataset (atomically) and return the file's path."""
    clean = []
    for row in rows:
        missing = {"method", "metric", "value"} - set(row)
        if missing:
            raise ValueError(f"record: row {row!r} lacks {sorted(missing)}")
        value = row["value"]
        clean.append({"method": str(row["method"]), "metric": str(row["metric"]),
                      "value": None if value is None else float(value),
                      "unit": str(row.get("unit", "")), "target": row.get("target")})
    if command is None:
        command = ".venv/bin/python " + " ".join(shlex.quote(a) for a in
                                                 [os.path.relpath(sys.argv[0], RESULTS.parents[1]), *sys.argv[1:]])
    doc = {"bench": bench, "dataset": dataset, "command": command,
           "date": _dt.date.today().isoformat(), "rows": clean}
    path = RESULTS / bench / f"{dataset}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(doc, indent=1) + "\n")
    os.replace(tmp, path)
    return path


def load_all() -> list[dict]:
    """Every recorded document, sorted by benchmark and dataset."""
    return [json.loads(p.read_text()) for p in sorted(RESULTS.glob("*/*.json"))]
