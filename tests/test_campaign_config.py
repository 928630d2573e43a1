"""Campaign file: loading, defaults, relative paths, round trip, and one-line errors."""

from __future__ import annotations

import dataclasses
import pathlib

import pytest
from rspiv.campaign_config import (
    CampaignConfig,
    load_campaign_config,
    parse_campaign_config,
)
from rspiv.campaign_schema import dump_toml
from rspiv.errors import InvalidInputError
from rspiv.settings import PivSettings

FULL = """
[campaign]
name = "tbl"

[calibration]
target = "cal/target.tif"
pitch_mm = 19.51
model = "R2"

[images]
glob = "raw/*.tif"
max_pairs = 4

[correction]
method = "I"

[piv]
passes = [[64, 64], [32, 8]]
overlap = 0.75

[wall]
side = "bottom"

[flow]
nu = 1.5e-5
dt = 5e-5

[statistics]
min_count = 3

[output]
dir = "out"
"""


def _write(tmp_path, text, name="campaign.toml"):
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def test_full_file_and_relative_paths(tmp_path):
    cfg = load_campaign_config(_write(tmp_path, FULL))
    base = tmp_path.resolve()
    assert cfg.name == "tbl" and cfg.source == base / "campaign.toml"
    assert cfg.calibration.target == base / "cal" / "target.tif"
    assert cfg.calibration.model == "R2" and cfg.calibration.pitch_sigma_mm == 0.02
    assert cfg.images.glob == str(base / "raw" / "*.tif") and cfg.images.max_pairs == 4
    assert cfg.correction.method == "I" and cfg.correction.map_displacement is True
    assert cfg.piv.passes == [(64, 64), (32, 8)] and cfg.piv.overlap == 0.75
    assert cfg.piv.median_threshold == 2.0  # default
    assert cfg.wall.side == "bottom" and cfg.wall.rotate is True
    assert cfg.flow.dt == 5e-5 and cfg.statistics.min_count == 3
    assert cfg.output.dir == base / "out"


def test_minimal_file_gets_defaults(tmp_path):
    cfg = load_campaign_config(
        _write(tmp_path, '[images]\nmultiframe = "run.tiff"\n[correction]\nmethod = "none"\n')
    )
    assert cfg.images.multiframe == tmp_path.resolve() / "run.tiff"
    assert cfg.piv.passes == [(64, 64), (32, 32), (32, 8)]
    assert cfg.output.dir == tmp_path.resolve() / "rspiv-out"
    assert cfg.flow.nu == 1.5e-5


def test_pairs_list_and_glob_pairing(tmp_path):
    for i in range(4):
        (tmp_path / f"f{i}.png").write_bytes(b"")
    cfg = load_campaign_config(
        _write(tmp_path, '[images]\nglob = "f*.png"\n[correction]\nmethod = "none"\n')
    )
    pairs = cfg.images.pair_files()
    assert [(a.name, b.name) for a, b in pairs] == [("f0.png", "f1.png"), ("f2.png", "f3.png")]
    cfg2 = load_campaign_config(
        _write(
            tmp_path,
            '[images]\npairs = [["a.bmp", "b.bmp"]]\n[correction]\nmethod = "none"\n',
            "c2.toml",
        )
    )
    assert cfg2.images.pair_files() == [
        (tmp_path.resolve() / "a.bmp", tmp_path.resolve() / "b.bmp")
    ]


@pytest.mark.parametrize("use_tomli_w", [True, False])
def test_round_trip_through_toml(tmp_path, use_tomli_w, monkeypatch):
    cfg = load_campaign_config(_write(tmp_path, FULL))
    if not use_tomli_w:
        import sys

        monkeypatch.setitem(sys.modules, "tomli_w", None)  # import fails -> built-in writer
    out = tmp_path / "sub" / "copy.toml"
    cfg.save(out)
    back = load_campaign_config(out)
    back.source = cfg.source = None
    assert back == cfg
    assert "../cal/target.tif" in out.read_text()  # relative to the new file's folder


def test_builtin_writer_escapes_strings():
    text = dump_toml({"campaign": {"name": 'a "q" \\ b', "description": "x\ny"}})
    import tomllib

    assert tomllib.loads(text)["campaign"] == {"name": 'a "q" \\ b', "description": "x\ny"}


@pytest.mark.parametrize(
    ("body", "message"),
    [
        (
            '[images]\nglob="a*.tif"\n[piv]\npasses = "abc"\n',
            "campaign.toml: [piv].passes: expected a list of [w, h] pairs, got 'abc'",
        ),
        (
            '[images]\nglob="a*.tif"\n[piv]\npasses = [[32, "8"]]\n',
            "campaign.toml: [piv].passes: expected a list of [w, h] pairs",
        ),
        (
            '[images]\nglob="a*.tif"\n[piv]\nwindow = 3\n',
            "campaign.toml: [piv].window: unknown key",
        ),
        ('[images]\nglob="a*.tif"\n[pivv]\n', "campaign.toml: [pivv]: unknown section"),
        (
            '[images]\nglob="a*.tif"\n[flow]\nnu = "water"\n',
            "campaign.toml: [flow].nu: expected a number, got 'water'",
        ),
        (
            '[images]\nglob="a*.tif"\n[flow]\nnu = -1.0\n',
            "campaign.toml: [flow].nu: expected a value >",
        ),
        ('[images]\nglob="a*.tif"\n[wall]\nrotate = 1\n', "[wall].rotate: expected true or false"),
        (
            '[images]\nglob="a*.tif"\n[correction]\nmethod = "III"\n',
            "[correction].method: expected one of 'I', 'II', 'none', got 'III'",
        ),
        ('[images]\nglob="a*.gif"\n', "[images].glob: expected an image file"),
        ('[images]\nglob="a*.tif"\nmultiframe="m.tif"\n', "[images]: expected exactly one of"),
        ("[piv]\noverlap = 0.5\n", "[images]: expected exactly one of glob, pairs, multiframe"),
        (
            '[images]\nglob="a*.tif"\n[correction]\nmethod = "II"\n',
            "[calibration].target: method 'II' needs a calibration target",
        ),
        (
            '[images]\nglob="a*.tif"\n[statistics]\nmin_count = 2.5\n',
            "[statistics].min_count: expected an integer",
        ),
        # malformed TOML: the message names the key of the offending line
        (
            '[images]\nglob="a*.tif"\n[piv]\npasses = [[64, 64]\n',
            "campaign.toml: [piv].passes: malformed TOML",
        ),
        ("[flow]\nnu = 1.5e-5 m2/s\n", "campaign.toml: [flow].nu: malformed TOML"),
        ("x = = 1\n", "campaign.toml: x: malformed TOML"),
        ("piv = 3\n", "campaign.toml: [piv]: expected a table, got 3"),
        ('[images]\nmultiframe = "m.png"\n', "[images].multiframe: expected a multi-frame TIFF"),
    ],
)
def test_errors_name_file_and_key(tmp_path, body, message):
    with pytest.raises(InvalidInputError) as info:
        load_campaign_config(_write(tmp_path, body))
    text = str(info.value)
    assert message in text and "\n" not in text


def test_missing_file_and_in_memory_parse(tmp_path):
    with pytest.raises(InvalidInputError, match="cannot read"):
        load_campaign_config(tmp_path / "nope.toml")
    cfg = parse_campaign_config(
        {"images": {"pairs": [["a.tif", "b.tif"]]}, "correction": {"method": "none"}},
        base=tmp_path,
    )
    assert cfg.images.pairs[0][0] == pathlib.Path(tmp_path).resolve() / "a.tif"
    assert isinstance(cfg, CampaignConfig)


def test_the_one_vocabulary_and_the_old_keys(tmp_path):
    """[piv] holds rspiv.PivSettings keys; methods and models in any case, with the API's
    aliases; the old keys median_epsilon / deform / map_displacement still read."""
    text = FULL.replace('model = "R2"', 'model = "p3"')
    text = text.replace('method = "I"', 'method = "vectors"')
    text = text.replace("overlap = 0.75", 'overlap = 0.75\ndeformation = "SYMMETRIC"\n'
                        'interpolation = "keys"\nmedian_eps = 0.2\niterations = 2')  # fmt: skip
    text = text.replace("[correction]\n", '[correction]\nmapping = "positions"\n')
    cfg = load_campaign_config(_write(tmp_path, text))
    assert cfg.calibration.model == "P3" and cfg.correction.method == "II"
    assert cfg.correction.mapping == "positions" and cfg.correction.map_displacement is False
    s = cfg.piv.settings()
    assert s == PivSettings(passes=((64, 64), (32, 8)), overlap=0.75, iterations=2,
                                  deformation="symmetric", interpolation="keys",
                                  median_eps=0.2)  # fmt: skip
    old = FULL.replace("overlap = 0.75", "overlap = 0.75\nmedian_epsilon = 0.3\ndeform = true")
    s = load_campaign_config(_write(tmp_path, old)).piv.settings()
    assert s.median_eps == 0.3 and s.deformation == "symmetric"
    assert load_campaign_config(_write(tmp_path, FULL)).piv.settings().deformation == "offset"
    both = FULL.replace("overlap = 0.75", "overlap = 0.75\nmedian_eps = 0.1\nmedian_epsilon = 0.3")
    with pytest.raises(InvalidInputError, match="given twice"):
        load_campaign_config(_write(tmp_path, both))
    bad = FULL.replace("overlap = 0.75", 'overlap = 0.75\ninterpolation = "cubic"')
    with pytest.raises(InvalidInputError, match=r"\[piv\]\.interpolation"):
        load_campaign_config(_write(tmp_path, bad))


def test_noise_correction_and_uncertainty_keys(tmp_path):
    """``[piv] uncertainty`` and ``[statistics] noise_correction`` read as booleans; the noise
    correction without the uncertainty it needs is a one-line error naming the key."""
    text = FULL.replace("overlap = 0.75", "overlap = 0.75\nuncertainty = false")
    cfg = load_campaign_config(_write(tmp_path, text))
    assert cfg.piv.uncertainty is False and cfg.piv.settings().uncertainty is False
    assert cfg.statistics.noise_correction is False
    on = FULL.replace("[statistics]\n", "[statistics]\nnoise_correction = true\n")
    assert load_campaign_config(_write(tmp_path, on)).statistics.noise_correction is True
    both = text.replace("[statistics]\n", "[statistics]\nnoise_correction = true\n")
    with pytest.raises(InvalidInputError, match=r"\[statistics\]\.noise_correction: needs"):
        load_campaign_config(_write(tmp_path, both))
    bad = FULL.replace("[statistics]\n", '[statistics]\nnoise_correction = "yes"\n')
    with pytest.raises(InvalidInputError, match=r"\[statistics\]\.noise_correction"):
        load_campaign_config(_write(tmp_path, bad))


def test_two_point_keys(tmp_path):
    """``[statistics] two_point``: off by default; the maps' heights a short increasing list,
    their units "delta" or "px"; anything else named in one line."""
    cfg = load_campaign_config(_write(tmp_path, FULL))
    assert cfg.statistics.two_point is False
    assert cfg.statistics.two_point_heights == (0.1, 0.3, 0.6)
    on = FULL.replace(
        "[statistics]\n",
        '[statistics]\ntwo_point = true\ntwo_point_heights = [200, 400]\n'
        'two_point_height_units = "PX"\ntwo_point_min_valid = 0.8\n',
    )
    st = load_campaign_config(_write(tmp_path, on)).statistics
    assert st.two_point and st.two_point_heights == (200.0, 400.0)
    assert st.two_point_height_units == "px" and st.two_point_min_valid == 0.8
    for key, value, msg in (
        ("two_point_heights", "[0.3, 0.1]", "increasing"),
        ("two_point_heights", "[0.1, -0.3]", "> 0"),
        ("two_point_height_units", '"mm"', "'delta', 'px'"),
        ("two_point_min_valid", "1.5", "<= 1"),
    ):
        bad = FULL.replace("[statistics]\n", f"[statistics]\n{key} = {value}\n")
        with pytest.raises(InvalidInputError, match=rf"\[statistics\]\.{key}: .*{msg}"):
            load_campaign_config(_write(tmp_path, bad))


def test_quadrant_keys(tmp_path):
    """``[statistics] quadrant``: off by default, and needs ``[output] fields`` (the second
    pass reads them); the hole sizes an increasing list of numbers >= 0; anything else named in
    one line."""
    cfg = load_campaign_config(_write(tmp_path, FULL))
    assert cfg.statistics.quadrant is False
    assert cfg.statistics.quadrant_holes == (0.0, 1.0, 2.0, 4.0)
    on = FULL.replace("[statistics]\n", "[statistics]\nquadrant = true\nquadrant_holes = [0, 3]\n")
    with pytest.raises(InvalidInputError, match=r"\[statistics\]\.quadrant: needs each pair's"):
        load_campaign_config(_write(tmp_path, on))
    with_fields = on.replace("[output]\n", "[output]\nfields = true\n")
    st = load_campaign_config(_write(tmp_path, with_fields))
    assert st.statistics.quadrant and st.statistics.quadrant_holes == (0.0, 3.0)
    for value, msg in (("[2, 1]", "increasing"), ("[-1]", ">= 0"), ("[]", "1 to 8"), ("2", "list")):
        bad = FULL.replace("[statistics]\n", f"[statistics]\nquadrant_holes = {value}\n")
        with pytest.raises(InvalidInputError, match=rf"\[statistics\]\.quadrant_holes: .*{msg}"):
            load_campaign_config(_write(tmp_path, bad))


def test_conditional_keys(tmp_path):
    """``[statistics] conditional``: off by default, needs ``[output] fields``; the heights 1 to
    8 increasing numbers > 0, in delta_99 or px, the hole >= 0; anything else named in one
    line."""
    st = load_campaign_config(_write(tmp_path, FULL)).statistics
    assert st.conditional is False and st.conditional_heights == (0.15, 0.4)
    assert st.conditional_height_units == "delta" and st.conditional_hole == 1.0
    keys = '[statistics]\nconditional = true\nconditional_heights = [40, 90]\n'
    keys += 'conditional_height_units = "PX"\nconditional_hole = 2\n'
    on = FULL.replace("[statistics]\n", keys)
    with pytest.raises(InvalidInputError, match=r"\[statistics\]\.conditional: needs each pair"):
        load_campaign_config(_write(tmp_path, on))
    with_fields = on.replace("[output]\n", "[output]\nfields = true\n")
    st = load_campaign_config(_write(tmp_path, with_fields)).statistics
    assert st.conditional and st.conditional_heights == (40.0, 90.0)
    assert st.conditional_height_units == "px" and st.conditional_hole == 2.0
    for key, value, msg in (
        ("conditional_heights", "[]", "1 to 8"),
        ("conditional_heights", "[0.4, 0.1]", "increasing"),
        ("conditional_heights", "[0]", "> 0"),
        ("conditional_height_units", '"mm"', "'delta', 'px'"),
        ("conditional_hole", "-1", ">= 0"),
        ("conditional", '"yes"', "true or false|boolean"),
    ):
        bad = FULL.replace("[statistics]\n", f"[statistics]\n{key} = {value}\n")
        with pytest.raises(InvalidInputError, match=rf"\[statistics\]\.{key}: .*({msg})"):
            load_campaign_config(_write(tmp_path, bad))


def test_vorticity_keys(tmp_path):
    """``[statistics] vorticity``: off by default, least-squares differences; the scheme one of
    the three (any case), anything else named in one line."""
    cfg = load_campaign_config(_write(tmp_path, FULL))
    assert cfg.statistics.vorticity is False and cfg.statistics.vorticity_scheme == "least_squares"
    keys = '[statistics]\nvorticity = true\nvorticity_scheme = "Central"\n'
    on = FULL.replace("[statistics]\n", keys)
    st = load_campaign_config(_write(tmp_path, on)).statistics
    assert st.vorticity and st.vorticity_scheme == "central"
    bad = FULL.replace("[statistics]\n", '[statistics]\nvorticity_scheme = "fourier"\n')
    with pytest.raises(InvalidInputError, match=r"\[statistics\]\.vorticity_scheme: .*richardson"):
        load_campaign_config(_write(tmp_path, bad))


def test_pod_keys(tmp_path):
    """``[statistics] pod``: off by default, needs ``[output] fields``; the modes 1-200, the
    snapshots >= 2, the height >= 0 (delta_99; 0 the whole flow side); anything else named in
    one line."""
    st = load_campaign_config(_write(tmp_path, FULL)).statistics
    assert (st.pod, st.pod_modes, st.pod_snapshots, st.pod_height) == (False, 10, 1000, 0.0)
    keys = "[statistics]\npod = true\npod_modes = 4\npod_snapshots = 50\npod_height = 1.2\n"
    on = FULL.replace("[statistics]\n", keys)
    with pytest.raises(InvalidInputError, match=r"\[statistics\]\.pod: needs each pair's"):
        load_campaign_config(_write(tmp_path, on))
    with_fields = on.replace("[output]\n", "[output]\nfields = true\n")
    s = load_campaign_config(_write(tmp_path, with_fields)).statistics
    assert (s.pod, s.pod_modes, s.pod_snapshots, s.pod_height) == (True, 4, 50, 1.2)
    for key, value, msg in (
        ("pod_modes", "0", ">= 1"),
        ("pod_modes", "201", "<= 200"),
        ("pod_modes", "2.5", "an integer"),
        ("pod_snapshots", "1", ">= 2"),
        ("pod_height", "-1", ">= 0"),
        ("pod", "1", "true or false|boolean"),
    ):
        bad = FULL.replace("[statistics]\n", f"[statistics]\n{key} = {value}\n")
        with pytest.raises(InvalidInputError, match=rf"\[statistics\]\.{key}: .*({msg})"):
            load_campaign_config(_write(tmp_path, bad))


def test_vortex_keys(tmp_path):
    """``[statistics] vortices``: off by default, needs ``[output] fields`` and the vorticity
    statistics (its threshold is their swirl's rms); threshold and min_diameter > 0."""
    st = load_campaign_config(_write(tmp_path, FULL)).statistics
    assert (st.vortices, st.vortex_threshold, st.vortex_min_diameter) == (False, 1.5, 1.0)
    assert st.vortex_fits is True  # with the vortices, their Lamb-Oseen fits (~0.2 ms a core)
    on = FULL.replace("[statistics]\n", "[statistics]\nvortices = true\nvortex_threshold = 2\n")
    on = on.replace("[output]\n", "[output]\nfields = true\n")
    with pytest.raises(InvalidInputError, match=r"\[statistics\]\.vortices: needs the vorticity"):
        load_campaign_config(_write(tmp_path, on))
    s = load_campaign_config(
        _write(tmp_path, on.replace("[statistics]\n", "[statistics]\nvorticity = true\n"))
    ).statistics
    assert s.vortices and s.vortex_threshold == 2.0
    for key, value, msg in (
        ("vortex_threshold", "0", "> 0"),
        ("vortex_min_diameter", "0", "> 0"),
        ("vortex_min_diameter", "true", "a number"),
        ("vortex_fits", "1", "true or false"),
    ):
        bad = FULL.replace("[statistics]\n", f"[statistics]\n{key} = {value}\n")
        with pytest.raises(InvalidInputError, match=rf"\[statistics\]\.{key}: .*{msg}"):
            load_campaign_config(_write(tmp_path, bad))


def test_check_pairs_key(tmp_path):
    """``[images] check_pairs``: the pairs checked for drift before the PIV, 5 by default, 0 off,
    a negative or fractional count named in one line; kept by the round trip."""
    assert load_campaign_config(_write(tmp_path, FULL)).images.check_pairs == 5
    on = FULL.replace("max_pairs = 4\n", "max_pairs = 4\ncheck_pairs = 0\n")
    cfg = load_campaign_config(_write(tmp_path, on))
    assert cfg.images.check_pairs == 0 and cfg.to_dict()["images"]["check_pairs"] == 0
    for value in ("-1", "2.5"):
        bad = FULL.replace("max_pairs = 4\n", f"max_pairs = 4\ncheck_pairs = {value}\n")
        with pytest.raises(InvalidInputError, match=r"\[images\]\.check_pairs") as exc:
            load_campaign_config(_write(tmp_path, bad))
        assert "\n" not in str(exc.value)


def test_to_dict_parses_back_to_the_same_campaign(tmp_path):
    """``CampaignConfig.to_dict()`` is TOML's own data (lists, not tuples): parsed as it is,
    without a TOML round trip, it gives the same campaign and the same dict."""
    cfg = load_campaign_config(_write(tmp_path, FULL))
    data = cfg.to_dict()
    back = parse_campaign_config(data, base=tmp_path)
    assert back.source is None  # not read from a file
    assert dataclasses.replace(back, source=cfg.source) == cfg and back.to_dict() == data
