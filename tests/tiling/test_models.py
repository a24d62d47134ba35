"""The tiles' models stream from their files in building order, one model of each tile at a time."""

from __future__ import annotations

import shapely

from rooftrace.model import BuildingModel, PartModel
from rooftrace.tiling.models import ModelStream, read_models, save_models


def _model(bid: int) -> BuildingModel:
    return BuildingModel(bid, [PartModel(1, shapely.box(0, 0, bid, 1))], {"status": "ok"})


def test_saved_models_read_back_one_at_a_time(tmp_path):
    path = tmp_path / "0_0.models"
    assert save_models(path, (_model(b) for b in (3, 1, 2))) == 3
    assert not list(tmp_path.glob("*.tmp"))
    back = read_models(path)
    first = next(back)  # the file is not held open between models: it can be replaced meanwhile
    assert first.building_id == 3 and first.parts[0].footprint.equals(shapely.box(0, 0, 3, 1))
    assert [m.building_id for m in back] == [1, 2]
    save_models(path, [])
    assert list(read_models(path)) == []


def test_tiles_merge_in_the_new_numbering_from_files_and_memory_alike(tmp_path):
    # tile 0 holds its buildings 1, 2 (new 2, 5), tile 1 its 1, 2, 3 (new 1, 3, 4): interleaved
    new_id = {(0, 1): 2, (0, 2): 5, (1, 1): 1, (1, 2): 3, (1, 3): 4}
    save_models(tmp_path / "a.models", [_model(1), _model(2)])
    tile1 = [_model(1), _model(2), _model(3)]
    stream = ModelStream([tmp_path / "a.models", tile1], new_id)
    merged = list(stream)
    assert [m.building_id for m in merged] == [1, 2, 3, 4, 5]
    # the footprint says which tile and tile id each came from
    assert [m.parts[0].footprint.bounds[2] for m in merged] == [1, 1, 2, 3, 2]
    # re-iterable; the models held in memory keep their tile ids
    assert [m.building_id for m in stream] == [1, 2, 3, 4, 5]
    assert [m.building_id for m in tile1] == [1, 2, 3]
