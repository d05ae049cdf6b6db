"""Soil patches in the episode metadata (``EpisodeMeta.patches``): recorded, read back, and old
metadata without them still reads."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from soil_bag_tools.bag_io import META_KEY, bag_custom_data, read_episode
from soil_msgs_py import graph as G
from soil_msgs_py.episode import EpisodeMeta
from soil_msgs_py.patches import MAX_PATCHES, SoilPatch, check_patches, parse_patch
from soil_physics.soils import MAX_SOIL_NAME_BYTES

SAMPLE = Path(__file__).resolve().parents[2] / "bags" / "samples" / "default_loam_id060_v0.50_d0.200_s7"
PATH = [SoilPatch(0.0, "Sand", 20.0).as_dict(), SoilPatch(5.0, "Clay", 90.0).as_dict()]


def meta(**kw) -> EpisodeMeta:
    return EpisodeMeta("Sand", 20.0, "fee", 3, 0.5, 0.1, 2.0, source="test", **kw)


def test_patches_round_trip_through_json_and_the_status_event():
    m = meta(patches=PATH)
    m.validate()
    back = EpisodeMeta.from_json(m.to_json())
    assert back == m and back.soil_patches() == (SoilPatch(0.0, "Sand", 20.0), SoilPatch(5.0, "Clay", 90.0))
    event = G.EpisodeEvent(G.EVENT_EPISODE_START, 0, m.name, m, 0, planned_ticks=120)
    assert G.EpisodeEvent.from_json(event.to_json()).meta == m


def test_a_one_soil_episode_has_no_patches_key_and_old_metadata_reads():
    m = meta()
    assert "patches" not in json.loads(m.to_json()) and m.name == "fee_sand_id020_v0.50_d0.100_s3"
    assert EpisodeMeta.from_json(m.to_json()) == m
    stored = json.loads(bag_custom_data(SAMPLE)[META_KEY])
    assert "patches" not in stored  # a bag from before patches existed
    ep = read_episode(SAMPLE)
    assert ep.meta.patches == [] and ep.meta.soil_patches() == ()


def test_episode_name_tells_paths_apart():
    a, b = meta(patches=PATH), meta(patches=[PATH[0], {**PATH[1], "x_start_m": 6.0}])
    assert a.name.startswith("fee_sand_id020_v0.50_d0.100_s3_p2-") and a.name != b.name
    assert a.name == meta(patches=list(PATH)).name  # stable


@pytest.mark.parametrize("patches, needle", [
    ([PATH[1], PATH[0]], r"patches\[1\]\.x_start_m=0\.0 must be greater than patches\[0\]\.x_start_m=5\.0"),
    ([{**PATH[0], "relative_density_pct": 101.0}], r"patches\[0\]\.relative_density_pct=101\.0 outside"),
    ([{**PATH[0], "extra": 1}], r"patches\[0\]=.* must have exactly the keys"),
    ("0:Sand:20", r"patches=.* must be a list"),
])
def test_bad_patches_in_metadata_are_named(patches, needle):
    with pytest.raises(ValueError, match=needle):
        meta(patches=patches).validate()


def test_the_longest_path_fits_its_episode_start_and_a_longer_one_is_refused_by_count():
    """The episode_start carries the path: a path of 1200 patches made an event its readers refused (the
    episode ran, no bag). The most patches allowed, each of a 64-byte soil name, still decode; one more is
    refused before anything runs, naming the count."""
    name = "é" * (MAX_SOIL_NAME_BYTES // 2)  # 64 bytes of a name JSON would escape to 192 characters
    path = [SoilPatch(0.1 * i + 1e-9, name, 100.0 / 3).as_dict() for i in range(MAX_PATCHES)]  # numbers of 17 digits
    m = meta(patches=path)
    m.validate()
    event = G.EpisodeEvent(G.EVENT_EPISODE_START, 0, m.name, m, 0, planned_ticks=120)
    assert len(event.to_json()) < G.MAX_JSON_CHARS and G.EpisodeEvent.from_json(event.to_json()).meta == m
    with pytest.raises(ValueError, match=rf"patches: {MAX_PATCHES + 1} patches, more than {MAX_PATCHES}"):
        check_patches(path + [SoilPatch(0.5 * MAX_PATCHES, "Sand", 50.0).as_dict()])


def test_where_bad_patches_came_from_is_said_once():
    with pytest.raises(ValueError) as err:
        check_patches([PATH[1], PATH[0]], "/sim/command: patches")
    text = str(err.value)
    assert text.startswith("/sim/command: patches[1].x_start_m=0.0 must be greater than patches[0].x_start_m=5.0")
    assert text.count("/sim/command") == 1


def test_entry_forms_are_one_patch():
    want = SoilPatch(5.0, "Clay", 90.0)
    assert parse_patch(" 5 : Clay :90") == want
    for form in ("5:Clay:90", (5.0, "Clay", 90), {"x_start_m": 5, "soil": "Clay", "relative_density_pct": 90}, want):
        assert check_patches([form]) == (want,)
    assert check_patches(None) == () == check_patches([])


def test_a_patch_from_behind_the_blade_start_is_taken_by_both_tools_written_as_a_separate_argument():
    """``--patch -3:Sand:20`` (x < 0) was refused by argparse as "expected one argument": a value
    starting with '-' that is no plain number reads as an option."""
    from soil_bringup.cut_report import parse_args as cut_args
    from soil_msgs_py.patches import glue_negative_patches
    from soil_sim_node.batch import parse_args as batch_args

    argv = ["--patch", "-3:Sand:20", "--patch", "-0.5:Loam:40", "--patch", "1.5:Clay:80"]
    assert glue_negative_patches(argv) == ["--patch=-3:Sand:20", "--patch=-0.5:Loam:40", "--patch", "1.5:Clay:80"]
    assert glue_negative_patches(["--patch", "--quiet", "-x"]) == ["--patch", "--quiet", "-x"]  # no value: argparse says so
    assert batch_args(["--out", "b", *argv]).patch == ["-3:Sand:20", "-0.5:Loam:40", "1.5:Clay:80"]
    assert check_patches(cut_args(argv).patch, "--patch")[0] == parse_patch("-3:Sand:20")


def test_episode_metadata_that_is_no_object_or_lacks_a_field_is_named():
    """An outside tester's bag metadata: without "soil" it read "EpisodeMeta.__init__() missing 1
    required positional argument", and a JSON list "unknown keys [1, 2]"."""
    import json

    import pytest

    from soil_msgs_py.episode import EpisodeMeta

    meta = EpisodeMeta("Clay", 40.0, "fee", 3, 0.5, 0.1, 2.0, source="test")
    assert EpisodeMeta.from_json(meta.to_json()) == meta
    data = json.loads(meta.to_json())
    del data["soil"]
    with pytest.raises(ValueError, match=r"episode metadata lacks the field\(s\) \['soil'\]"):
        EpisodeMeta.from_json(json.dumps(data))
    with pytest.raises(ValueError, match="must be a JSON object of its fields, not a list"):
        EpisodeMeta.from_json("[1, 2]")
