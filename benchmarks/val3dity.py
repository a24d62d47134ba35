"""val3dity, the reference ISO 19107 validator, on a CityJSON / CityJSONSeq file: valid solids per LoD and error codes.

val3dity is a checking tool, not a dependency: build it once with
``bash ../shared/tools/val3dity/build.sh`` (about 4 minutes; it lands in
``/opt/val3dity/bin/val3dity``), or point ``$VAL3DITY`` at a binary.  Without
it, :func:`validate` returns None and the command line says how to build it
and exits 0, so benchmarks and tests skip cleanly.

Usage::

    .venv/bin/python benchmarks/val3dity.py delft.city.jsonl [--json]

val3dity exits 0 even for invalid input; the figures come from its
``--report`` JSON: every error it lists carries the id
``coid=<CityObject>|geom=<index>|...`` of the geometry it is in, and the
geometry's LoD is read from the input file itself.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from collections import Counter, defaultdict
from pathlib import Path

__all__ = ["find_val3dity", "validate", "BUILD_HINT"]

#: where build.sh installs the binary by default
DEFAULT_BINARY = Path("/opt/val3dity/bin/val3dity")
BUILD_HINT = "val3dity is not built; run: bash ../shared/tools/val3dity/build.sh (about 4 minutes)"
_GEOM_ID = re.compile(r"coid=(.+)\|geom=(\d+)")


def find_val3dity() -> Path | None:
    """The val3dity binary: ``$VAL3DITY``, then ``val3dity`` on the PATH, then build.sh's default; None if absent."""
    for candidate in (os.environ.get("VAL3DITY"), shutil.which("val3dity"), str(DEFAULT_BINARY)):
        if candidate and Path(candidate).is_file() and os.access(candidate, os.X_OK):
            return Path(candidate)
    return None


def _solids(path: Path) -> dict[tuple[str, int], str]:
    """``(CityObject id, geometry index) -> LoD`` of every Solid / MultiSolid / CompositeSolid in the file."""
    def objects():
        text = path.read_text(encoding="utf-8")
        if path.name.endswith(".jsonl"):
            for line in text.splitlines():
                if line.strip():
                    doc = json.loads(line)
                    yield from doc.get("CityObjects", {}).items()
        else:
            yield from json.loads(text).get("CityObjects", {}).items()

    out = {}
    for coid, obj in objects():
        for k, geom in enumerate(obj.get("geometry", [])):
            if geom.get("type") in ("Solid", "MultiSolid", "CompositeSolid"):
                out[(coid, k)] = str(geom.get("lod"))
    return out


def validate(path: str | os.PathLike, *, binary: str | os.PathLike | None = None, timeout: float = 3600.0) -> dict | None:
    """Run val3dity on a CityJSON (``.city.json``) or CityJSONSeq (``.city.jsonl``) file.

    Parameters
    ----------
    path : path-like
    binary : path-like, optional
        val3dity executable; default :func:`find_val3dity`.
    timeout : float
        Seconds before giving up.

    Returns
    -------
    dict or None
        None when val3dity is not built.  Otherwise ``{"lod": {lod: {"solids",
        "valid", "share"}}, "errors": {code: count}, "error_names": {code:
        description}, "invalid": [(CityObject id, lod, [codes])], "feature_errors":
        {code: count}, "dataset_errors": [...], "features": n}``; ``share`` is
        the fraction of the LoD's solids with no error.
    """
    exe = Path(binary) if binary is not None else find_val3dity()
    if exe is None:
        return None
    path = Path(path)
    solids = _solids(path)
    with tempfile.TemporaryDirectory() as tmp:
        report_path = Path(tmp) / "report.json"
        proc = subprocess.run([str(exe), str(path), "--report", str(report_path)], capture_output=True, text=True,
                              timeout=timeout)
        if not report_path.exists():
            raise RuntimeError(f"val3dity wrote no report for {path} (exit {proc.returncode}): "
                               f"{(proc.stderr or proc.stdout).strip()[-500:]}")
        report = json.loads(report_path.read_text())

    bad: dict[tuple[str, int], set] = defaultdict(set)
    errors, feature_errors, names = Counter(), Counter(), {}
    for feature in report.get("features", []):
        for err in feature.get("errors", []):
            code = int(err["code"])
            names[code] = err.get("description", "")
            errors[code] += 1
            m = _GEOM_ID.search(str(err.get("id", "")))
            if m and (m.group(1), int(m.group(2))) in solids:
                bad[(m.group(1), int(m.group(2)))].add(code)
            else:  # between objects (e.g. overlapping parts) or of the feature as a whole
                feature_errors[code] += 1
    dataset_errors = report.get("dataset_errors", [])
    for err in dataset_errors:
        code = int(err.get("code", 0))
        names[code] = err.get("description", "")
        errors[code] += 1
    per_lod: dict[str, dict] = {}
    for key, lod in solids.items():
        row = per_lod.setdefault(lod, {"solids": 0, "valid": 0})
        row["solids"] += 1
        row["valid"] += key not in bad
    for row in per_lod.values():
        row["share"] = row["valid"] / row["solids"] if row["solids"] else float("nan")
    return {
        "lod": dict(sorted(per_lod.items())),
        "errors": dict(sorted(errors.items())),
        "error_names": dict(sorted(names.items())),
        "invalid": sorted((coid, solids[(coid, k)], sorted(codes)) for (coid, k), codes in bad.items()),
        "feature_errors": dict(sorted(feature_errors.items())),
        "dataset_errors": dataset_errors,
        "features": len(report.get("features", [])),
    }


def main(argv: list[str]) -> int:
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__)
        return 0
    result = validate(argv[0])
    if result is None:
        print(BUILD_HINT, file=sys.stderr)
        return 0
    if "--json" in argv:
        print(json.dumps(result, indent=1))
        return 0
    for lod, row in result["lod"].items():
        print(f"LoD {lod}: {row['valid']}/{row['solids']} solids valid ({100 * row['share']:.1f} %)")
    for code, n in result["errors"].items():
        print(f"  error {code} ({result['error_names'].get(code, '')}): {n}")
    if result["dataset_errors"]:
        print(f"  dataset errors: {result['dataset_errors']}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
