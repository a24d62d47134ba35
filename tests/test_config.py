"""Config files are checked whole when read: tables, keys, types and ranges, naming the file (issue 10)."""

from __future__ import annotations

import pytest

from rooftrace.config import load_config
from rooftrace.errors import InputError
from rooftrace.options import make_options


def _cfg(tmp_path, text):
    path = tmp_path / "c.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("text,match", [
    ("[segmnet]\nmin_height = 2\n", r"c\.toml: unknown section\(s\) segmnet; known: .*segment"),
    ("[alpha]\nstrategie = 'point'\n", r"c\.toml: \[alpha\] has unknown key\(s\) strategie; known: .*strategy"),
    ("[ground]\niteration_distance = 'far'\n", r"c\.toml: \[ground\] iteration_distance must be a number, got 'far'"),
    ("[surface]\nenabled = 1\n", r"c\.toml: \[surface\] enabled must be true or false"),
    ("[alpha]\nstrategy = 'sideways'\n", r"c\.toml: \[alpha\] strategy must be one of .*sideways"),
    ("[classify]\nneighbours = 2\n", r"c\.toml: \[classify\] neighbours must be >= 4, got 2$"),
    ("[segment]\nmin_height = -3\n", r"c\.toml: \[segment\] min_height must be >= 0 m, got -3"),
    ("[planes]\nhold_step_boundaries = true\n",
     r"c\.toml: \[planes\] hold_step_boundaries is no longer an option; use face_boundaries = \"held\""),
    ("[mrf]\nbeta = -1\n", r"c\.toml: \[mrf\]"),
    ("seed = 1\n", r"c\.toml: top-level key 'seed' must be a \[table\]"),
    ("[ground\n", r"c\.toml: not valid TOML"),
])
def test_bad_config_is_refused_when_read(tmp_path, text, match):
    with pytest.raises(InputError, match=match):
        load_config(_cfg(tmp_path, text))


def test_a_table_read_by_another_command_is_checked_too(tmp_path):
    # detect never reads [snake], but a typo there must not wait for 'rooftrace snake' to surface
    with pytest.raises(InputError, match=r"\[snake\] has unknown key\(s\) stepz"):
        load_config(_cfg(tmp_path, "[segment]\nmin_height = 2.5\n[snake]\nstepz = 3\n"))


def test_contour_corners_and_harris_have_their_own_tables(tmp_path):
    """[corners] is the outline's Douglas-Peucker/angle filter, [harris] the image corner detector."""
    from rooftrace.contour.corners import CornerOptions
    from rooftrace.image.corners import HarrisOptions

    cfg = load_config(_cfg(tmp_path, "[corners]\nt_dist = 0.5\n[harris]\nk = 0.05\n"))
    assert make_options(CornerOptions, cfg).t_dist == 0.5
    assert make_options(HarrisOptions, cfg).k == 0.05
    with pytest.raises(InputError, match=r"\[corners\] has unknown key\(s\) k;"):
        load_config(_cfg(tmp_path, "[corners]\nk = 0.05\n"))
    with pytest.raises(InputError, match=r"\[harris\] (harris\.)?k must be in"):
        load_config(_cfg(tmp_path, "[harris]\nk = 0.5\n"))


def test_one_table_per_options_dataclass_and_every_section_named_by_its_dataclass():
    """The table is explicit: each dataclass's ``section`` is its key, and no two tables share a dataclass."""
    import dataclasses

    from rooftrace.config import SECTIONS

    assert all(cls.section == name and dataclasses.is_dataclass(cls) for name, cls in SECTIONS.items())
    assert len(set(SECTIONS.values())) == len(SECTIONS)


def test_unknown_keys_are_refused_in_every_table_and_tiling_is_a_table(tmp_path):
    from rooftrace.config import SECTIONS
    from rooftrace.tiling import TileOptions

    for section in SECTIONS:
        with pytest.raises(InputError, match=rf"\[{section}\] has unknown key\(s\) typo_key"):
            load_config(_cfg(tmp_path, f"[{section}]\ntypo_key = 1\n"))
    cfg = load_config(_cfg(tmp_path, "[tiling]\ntile_size = 250\n[run]\nplanes = false\n"))
    assert make_options(TileOptions, cfg).tile_size == 250


def test_run_options_from_the_config_and_the_flags(tmp_path):
    from rooftrace.config import RunOptions

    cfg = load_config(_cfg(tmp_path, "[run]\nalpha = 'global'\nplanes = false\n[segment]\nmin_height = 2.5\n"))
    options = RunOptions.from_config(cfg)
    assert (options.alpha, options.planes, options.outline.alpha.strategy) == ("global", False, "global")
    assert options.detect.segment.min_height == 2.5
    flagged = RunOptions.from_config(cfg, alpha="point", planes=True)  # a flag wins over the file
    assert (flagged.alpha, flagged.planes, flagged.outline.alpha.strategy) == ("point", True, "point")
    with pytest.raises(InputError, match="alpha must be"):
        load_config(_cfg(tmp_path, "[run]\nalpha = 'sideways'\n"))


def test_good_config_and_overrides(tmp_path):
    from rooftrace.lidar.segment import SegmentOptions

    cfg = load_config(_cfg(tmp_path, "[segment]\nmin_height = 2.5\n[alpha]\nstrategy = 'building'\n"))
    assert make_options(SegmentOptions, cfg).min_height == 2.5
    assert make_options(SegmentOptions, cfg, min_height=3.0).min_height == 3.0  # a CLI flag wins
    assert load_config(None) == {}


def test_false_switches_an_optional_test_off(tmp_path):
    """TOML has no null: `false` turns off a test that defaults to a value, `"auto"` derives one."""
    from rooftrace.lidar.classify import ClassifyOptions
    from rooftrace.lidar.detect import DetectOptions
    from rooftrace.lidar.segment import SegmentOptions
    from rooftrace.refine.options import RefineOptions

    assert ClassifyOptions().max_penetration is not None and SegmentOptions().min_width is not None
    cfg = load_config(_cfg(tmp_path, "[classify]\nmax_penetration = false\nmax_patch_penetration = false\n"
                                     "penetration_edge = false\n[segment]\nmin_width = false\n"
                                     "[refine]\nsimplify_tolerance = 'auto'\n"))
    opts = DetectOptions.from_config(cfg)
    assert (opts.classify.max_penetration, opts.classify.max_patch_penetration, opts.classify.penetration_edge,
            opts.segment.min_width) == (None, None, None, None)
    assert RefineOptions.from_config(cfg).simplify_tolerance is None
    # numbers still set them, and 0 is a number, not "off"
    cfg = load_config(_cfg(tmp_path, "[classify]\nmax_penetration = 0.4\n[refine]\nsimplify_tolerance = 0\n"))
    assert make_options(ClassifyOptions, cfg).max_penetration == 0.4
    assert RefineOptions.from_config(cfg).simplify_tolerance == 0.0


@pytest.mark.parametrize("text,match", [
    ("[classify]\nmax_penetration = true\n", r"\[classify\] max_penetration must be a number or false, got True"),
    ("[refine]\nsimplify_tolerance = false\n", r"\[refine\] simplify_tolerance must be a number or \"auto\""),
    ("[segment]\nmin_width = 'auto'\n", r"\[segment\] min_width must be a number or false, got 'auto'"),
    ("[segment]\nmin_height = false\n", r"\[segment\] min_height must be a number, got False"),
])
def test_none_is_spelled_only_where_it_means_something(tmp_path, text, match):
    with pytest.raises(InputError, match=match):
        load_config(_cfg(tmp_path, text))
