import json

import pytest

from rooftrace.cli.main import main


def test_simulate_writes_the_scene_and_refuses_to_overwrite(tmp_path, capsys):
    out = tmp_path / "scene"
    code = main(["simulate", "-o", str(out), "--size", "40", "--density", "4", "--seed", "2", "--json", "-q"])
    assert code == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["seed"] == 2 and summary["points"] > 4 * 40 * 40 * 0.9
    assert summary["roof_density"] == pytest.approx(4.0, rel=0.25)
    for name in ("points.laz", "image.tif", "camera.json", "truth.gpkg"):
        assert (out / name).is_file()
    code = main(["simulate", "-o", str(out), "--size", "40", "--density", "4"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error:") and "--overwrite" in err
    code = main(["simulate", "-o", str(out), "--size", "40", "--density", "4", "--overwrite", "--no-image", "-q"])
    assert code == 0


def test_simulate_blocks_scene(tmp_path, capsys):
    code = main(["simulate", "-o", str(tmp_path / "b"), "--scene", "blocks", "--size", "80", "--density", "2",
                 "--no-image", "--json", "-q"])
    assert code == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["buildings"] > 20 and summary["truth_classes"]["6"] > 0


def test_simulate_orthophoto_and_config(tmp_path, capsys):
    cfg = tmp_path / "sim.toml"
    cfg.write_text("[simulate]\nsize = 40\ndensity = 3\ntrees = false\n")
    code = main(["simulate", "-o", str(tmp_path / "o"), "--config", str(cfg), "--orthophoto", "--gsd", "0.4", "--json"])
    assert code == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["image_size"] == [100, 100]
    assert json.loads((tmp_path / "o" / "camera.json").read_text())["type"] == "orthophoto"


@pytest.mark.parametrize("args, match", [
    (["--density", "-1"], "density"),
    (["--orthophoto", "--perturb-camera", "2"], "perturb-camera"),
    (["--size", "1"], "size"),
    (["--scene", "downtown"], "scene"),
])
def test_simulate_bad_input_is_one_error_line(tmp_path, capsys, args, match):
    code = main(["simulate", "-o", str(tmp_path / "x"), *args])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith("error:") and match in err and len(err.strip().splitlines()) == 1


def test_simulate_bad_config_key(tmp_path, capsys):
    cfg = tmp_path / "bad.toml"
    cfg.write_text("[simulate]\ndensty = 3\n")
    assert main(["simulate", "-o", str(tmp_path / "x"), "--config", str(cfg)]) == 2
    assert "densty" in capsys.readouterr().err
