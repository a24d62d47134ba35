"""The tiles' 3D models on disk, streamed: written one by one, merged in building order one at a time.

A tile's models are the bulk of its result (every solid of every level of
detail); held for all tiles until the end, the parent's memory would grow
with the city.  :func:`save_models` writes a tile's models to a file of
its own, one pickle after the other, in the order the merge numbers them;
:class:`ModelStream` joins the tiles' files in building-id order
(:func:`heapq.merge`), reading one model of each tile at a time and
re-opening the file for each read, so that neither the models nor the
open files grow with the number of tiles.
"""

from __future__ import annotations

import copy
import heapq
import os
import pickle
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path

from rooftrace.model.types import BuildingModel

__all__ = ["save_models", "read_models", "ModelStream"]


def save_models(path: os.PathLike, models: Iterable[BuildingModel]) -> int:
    """Write ``models`` to ``path``, one pickle each, through a temporary file renamed when complete.

    Returns
    -------
    int
        Models written.
    """
    path = Path(path)
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    count = 0
    with tmp.open("wb") as f:
        for model in models:
            pickle.dump(model, f, protocol=pickle.HIGHEST_PROTOCOL)
            count += 1
    os.replace(tmp, path)
    return count


def read_models(path: os.PathLike) -> Iterator[BuildingModel]:
    """The models of a :func:`save_models` file, one at a time (the file is open only while one is read)."""
    offset = 0
    while True:
        with open(path, "rb") as f:
            f.seek(offset)
            try:
                model = pickle.load(f)
            except EOFError:
                return
            offset = f.tell()
        yield model


class ModelStream:
    """The models of several tiles, renumbered and in building-id order, read lazily (re-iterable).

    Parameters
    ----------
    sources : sequence of (path or list of BuildingModel)
        Per tile, its :func:`save_models` file or its models in memory, each
        in the tile's merge order (increasing new id).
    new_id : mapping of (tile position, tile id) to int
        The merged number of every owned building
        (:func:`rooftrace.tiling.tile.building_numbers`).

    Notes
    -----
    Iterating gives each model with ``building_id`` set to its merged
    number; the files must stay until the stream is read (the run folder).
    """

    def __init__(self, sources: Sequence, new_id: Mapping[tuple[int, int], int]):
        self.sources = list(sources)
        self.new_id = dict(new_id)

    def _tile(self, t: int) -> Iterator[tuple[int, BuildingModel]]:
        src = self.sources[t]
        on_disk = isinstance(src, (str, os.PathLike))
        for model in read_models(src) if on_disk else src:
            model = model if on_disk else copy.copy(model)  # the caller's models keep their tile ids
            model.building_id = self.new_id[(t, model.building_id)]
            yield model.building_id, model

    def __iter__(self) -> Iterator[BuildingModel]:
        for _, model in heapq.merge(*(self._tile(t) for t in range(len(self.sources))), key=lambda x: x[0]):
            yield model
