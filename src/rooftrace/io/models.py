"""Model outputs chosen by their file name: ``.city.jsonl``, ``.city.json``, ``.obj`` (and ``.gpkg`` layers).

:func:`output_format` names the format of a path (commands call it before
any work, so a wrong name fails at once); :func:`write_models` streams one
iterable of models into any number of model files in a single pass.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from contextlib import ExitStack
from pathlib import Path

from rooftrace.errors import InputError

__all__ = ["output_format", "write_models", "MODEL_FORMATS"]

#: file name ending -> format, longest endings first
MODEL_FORMATS = {".city.jsonl": "cityjsonseq", ".city.json": "cityjson", ".obj": "obj", ".gpkg": "gpkg"}


def output_format(path: str | os.PathLike) -> str:
    """``cityjsonseq``, ``cityjson``, ``obj`` or ``gpkg`` from the name of ``path``.

    Raises
    ------
    InputError
        Any other ending (``.json`` alone, ``.jsonl``, ``.geojson`` ...).

    Examples
    --------
    >>> output_format("delft.city.jsonl"), output_format("a.CITY.JSON"), output_format("x.gpkg")
    ('cityjsonseq', 'cityjson', 'gpkg')
    """
    name = Path(path).name.lower()
    for ending, fmt in MODEL_FORMATS.items():
        if name.endswith(ending):
            return fmt
    raise InputError(f"{path}: unknown output format; name it *.gpkg (layers), *.city.jsonl (CityJSONSeq), "
                     "*.city.json (CityJSON 2.0) or *.obj")


def write_models(paths: Sequence[str | os.PathLike], models: Iterable, crs=None, *, overwrite: bool = False) -> int:
    """Write the same models to every file of ``paths`` (CityJSONSeq, CityJSON or OBJ), in one pass.

    Each model is serialised as it comes and dropped, so ``models`` may be a
    generator over a city.  Every file is written to a temporary name and
    renamed when complete; on an error none is replaced.

    Returns
    -------
    int
        Buildings written.
    """
    from rooftrace.io.cityjson import CityJSONSeqWriter, CityJSONWriter
    from rooftrace.io.obj import OBJWriter

    kinds = {"cityjsonseq": CityJSONSeqWriter, "cityjson": CityJSONWriter, "obj": OBJWriter}
    count = 0
    with ExitStack() as stack:
        writers = []
        for p in paths:
            fmt = output_format(p)
            if fmt not in kinds:
                raise InputError(f"{p}: {fmt} is not a model file format")
            writers.append(stack.enter_context(kinds[fmt](p, crs, overwrite=overwrite)))
        for model in models:
            for w in writers:
                w.add(model)
            count += 1
    return count
