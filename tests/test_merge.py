"""``rspiv merge``: shard files of a tiny synthetic campaign merged back into the statistics of
the unsharded run; any order gives the same bits; a pair, shard or file is never counted twice.
"""

from __future__ import annotations

import pathlib
import shutil

import numpy as np
import pytest
import rspiv
from rspiv.campaign import Campaign
from rspiv.cli import main
from rspiv.merge import merge_files, read_part
from scaleout_cases import assert_same_statistics, make_campaign, prepared_copy

N_PAIRS = 6
RUN = "method_II"


@pytest.fixture(scope="module")
def case(tmp_path_factory):  # (unsharded run, folder of shard files 1..3/3 and 1/2)
    d = tmp_path_factory.mktemp("merge")
    toml = make_campaign(d, N_PAIRS)
    full = Campaign.load(toml, progress=False).run()
    out = prepared_copy(full.out_dir, d / "sharded")
    for shard in ("1/3", "2/3", "3/3", "1/2"):
        r = Campaign.load(toml, progress=False, out_dir=out, shard=shard).run()
        assert not r.analyses and r.files
    return full, out / "shards"


def _parts(shards: pathlib.Path, n: int = 3, run: str = RUN) -> list[pathlib.Path]:
    return [shards / f"statistics_{run}.shard-{i}-of-{n}.nc" for i in range(1, n + 1)]


def test_shard_files_carry_their_pairs(case):
    _, shards = case
    ids = [read_part(p).accumulator.pair_ids for p in _parts(shards)]
    assert ids == [{0, 1}, {2, 3}, {4, 5}]
    assert read_part(_parts(shards)[1]).shards == ["2/3"]


def test_merge_in_any_order_gives_the_full_statistics(case, tmp_path):
    full, shards = case
    parts = _parts(shards)
    results = []
    orders = [parts, parts[::-1], parts[1:] + parts[:1], [parts[1], parts[0], parts[2]]]
    for k, perm in enumerate(orders):
        path = merge_files(perm, tmp_path / f"m{k}.nc")[RUN]
        results.append(read_part(path))
    first = results[0].accumulator
    for r in results[1:]:  # canonical order: identical bits whatever the order given
        for name in ("count", "mean_u", "mean_v", "m2_uu", "m2_vv", "c_uv", "lag_c_u"):
            np.testing.assert_array_equal(getattr(r.accumulator, name), getattr(first, name))
    # the unsharded run's statistics (lag-1 chains are cut at the shard boundaries)
    assert_same_statistics(full.accumulators[RUN], first, rtol=1e-12, lag=False)
    m = results[0]
    assert m.attrs["shards"] == "1/3,2/3,3/3" and m.attrs["run"] == RUN
    assert m.x is not None and m.y is not None


def test_nested_merges_equal_one_merge(case, tmp_path):
    full, shards = case
    p1, p2, p3 = _parts(shards)
    m12 = merge_files([p2, p1], tmp_path / "m12.nc")[RUN]
    nested = read_part(merge_files([p3, m12], tmp_path / "m123.nc")[RUN]).accumulator
    flat = read_part(merge_files([p1, p2, p3], tmp_path / "flat.nc")[RUN]).accumulator
    assert_same_statistics(flat, nested, rtol=1e-14, lag=False)
    assert_same_statistics(full.accumulators[RUN], nested, rtol=1e-12, lag=False)


def test_the_same_shard_twice_is_refused(case, tmp_path):
    _, shards = case
    p1, p2, p3 = _parts(shards)
    # the same file twice
    with pytest.raises(rspiv.InvalidInputError, match="given twice"):
        merge_files([p1, p2, p1], tmp_path / "x.nc")
    # a copy of a shard under another name
    dup = tmp_path / "copy_of_shard_2.nc"
    shutil.copy(p2, dup)
    with pytest.raises(rspiv.InvalidInputError, match="shard 2/3 is already in"):
        merge_files([p1, p2, dup], tmp_path / "x.nc")
    # a merged file together with one of its shards
    m12 = merge_files([p1, p2], tmp_path / "m12.nc")[RUN]
    with pytest.raises(rspiv.InvalidInputError, match="shard 2/3 is already in"):
        merge_files([m12, p2], tmp_path / "x.nc")
    # overlapping pairs from two different splittings (1/2 holds pairs 0, 1, 2)
    half = shards / f"statistics_{RUN}.shard-1-of-2.nc"
    with pytest.raises(rspiv.InvalidInputError, match=r"2 pair\(s\) already in .* \(e.g. 0, 1\)"):
        merge_files([p1, half], tmp_path / "x.nc")
    assert not (tmp_path / "x.nc").exists()


def test_incompatible_parts_are_refused(case, tmp_path):
    _, shards = case
    p1 = _parts(shards)[0]
    u2 = _parts(shards, run="uncorrected")[1]
    with pytest.raises(rspiv.InvalidInputError, match="2 runs"):
        merge_files([p1, u2], tmp_path / "x.nc")
    bad = tmp_path / "bad.nc"
    bad.write_bytes(b"not a netcdf file")
    with pytest.raises(rspiv.InvalidInputError, match="bad.nc: cannot read"):
        merge_files([p1, bad], tmp_path / "x.nc")
    # a part whose HDF5 global heap is damaged (no checksum there; HDF5 can loop forever on
    # one): refused in one line before HDF5 reads it (rspiv.hdf5_check)
    data = bytearray(p1.read_bytes())
    g = data.find(b"GCOL")
    assert g > 0
    data[g + 8 : g + 16] = (1 << 40).to_bytes(8, "little")
    heap = tmp_path / "heap.nc"
    heap.write_bytes(bytes(data))
    with pytest.raises(rspiv.InvalidInputError, match="heap.nc: cannot read .*global heap") as e:
        merge_files([p1, heap], tmp_path / "x.nc")
    assert "\n" not in str(e.value)
    # parts of several runs into a folder: one file per run
    parts = _parts(shards) + _parts(shards, run="uncorrected")
    written = merge_files(parts, tmp_path / "merged")
    assert set(written) == {RUN, "uncorrected"}
    assert written["uncorrected"] == tmp_path / "merged" / "statistics_uncorrected.nc"


def test_cli_merge(case, tmp_path, capsys):
    full, shards = case
    p1, p2, p3 = _parts(shards)
    out = tmp_path / "stats.nc"
    assert main(["merge", str(p3), str(p1), "-o", str(out)]) == 0
    cap = capsys.readouterr()
    assert f"wrote {out}" in cap.out and "shard(s) 2/3 not merged yet" in cap.err
    assert main(["merge", str(out), str(p2), "-o", str(tmp_path / "all.nc")]) == 0
    acc = read_part(tmp_path / "all.nc").accumulator
    assert_same_statistics(full.accumulators[RUN], acc, rtol=1e-12, lag=False)
    # refusal: exit code 2 and a one-line message naming the file
    assert main(["merge", str(out), str(p1), "-o", str(tmp_path / "no.nc")]) == 2
    err = capsys.readouterr().err
    assert "rspiv merge: error:" in err and p1.name in err


def test_merge_campaign_analyses_the_merged_shards(case, tmp_path, capsys):
    full, shards = case
    toml = full.out_dir.parent / "campaign.toml"
    # a folder with one complete splitting (3 shards of every run)
    out = prepared_copy(full.out_dir, tmp_path / "out")
    (out / "shards").mkdir()
    for f in shards.glob("*.shard-*-of-3.nc"):
        shutil.copy(f, out / "shards" / f.name)
    assert main(["merge", "--campaign", str(toml), "-o", str(out), "-q"]) == 0
    assert f"merged {N_PAIRS} pair(s) of 2 run(s)" in capsys.readouterr().out
    import pickle

    state = pickle.loads((out / "checkpoint" / "state.pkl").read_bytes())
    assert set(state["finished"]) == set(range(N_PAIRS))
    for run, ref in full.accumulators.items():
        assert_same_statistics(ref, state["accumulators"][run], rtol=1e-12, lag=False)
        assert (out / f"statistics_{run}.nc").is_file() and (out / f"profile_{run}.csv").is_file()
    # no pair was processed again: the analysis ran on the merged checkpoint
    import json

    ev = [json.loads(x) for x in (out / "run_log.jsonl").read_text().splitlines()]
    assert ev[0]["event"] == "start" and ev[0]["resumed"] == N_PAIRS
    assert not [e for e in ev if e["event"] == "pair"]


def test_merge_campaign_refuses_incomplete_or_mixed_shards(case, tmp_path):
    from rspiv.merge import merge_campaign

    full, shards = case
    toml = full.out_dir.parent / "campaign.toml"
    out = prepared_copy(full.out_dir, tmp_path / "out")
    (out / "shards").mkdir()
    for f in shards.glob("*.shard-*.nc"):  # 1..3 of 3 and 1 of 2
        shutil.copy(f, out / "shards" / f.name)
    with pytest.raises(rspiv.InvalidInputError, match="several splittings"):
        merge_campaign(Campaign.load(toml, progress=False, out_dir=out))
    for f in (out / "shards").glob("*-of-2.nc"):
        f.unlink()
    for f in (out / "shards").glob("*.shard-2-of-3.nc"):
        f.unlink()
    with pytest.raises(rspiv.InvalidInputError, match=r"shard\(s\) 2/3 missing"):
        merge_campaign(Campaign.load(toml, progress=False, out_dir=out))


def test_merge_campaign_refuses_a_shard_of_another_configuration(case, tmp_path):
    """A shard processed with other settings (here the median test's threshold) holds other
    statistics: among the campaign's own shards it is refused in one line naming its file, not
    summed in, and nothing is written."""
    import xarray as xr
    from rspiv.campaign_config import load_campaign_config
    from rspiv.merge import merge_campaign

    full, shards = case
    toml = full.out_dir.parent / "campaign.toml"
    cfg = load_campaign_config(toml)
    cfg.piv.median_threshold = 3.0
    other = prepared_copy(full.out_dir, tmp_path / "other")
    assert not Campaign(cfg, progress=False, out_dir=other, shard="2/3").run().analyses
    name = f"statistics_{RUN}.shard-2-of-3.nc"
    fps = []
    for p in (shards / name, other / "shards" / name):
        with xr.open_dataset(p, engine="h5netcdf") as ds:
            fps.append(ds.attrs["fingerprint"])
    assert fps[0] != fps[1]  # the setting is part of the configuration's fingerprint
    out = prepared_copy(full.out_dir, tmp_path / "out")
    (out / "shards").mkdir()
    for f in shards.glob("*.shard-*-of-3.nc"):
        shutil.copy(f, out / "shards" / f.name)
    shutil.copy(other / "shards" / name, out / "shards" / name)
    with pytest.raises(rspiv.InvalidInputError, match="written for another configuration") as e:
        merge_campaign(Campaign.load(toml, progress=False, out_dir=out))
    said = str(e.value)
    assert str(out / "shards" / name) in said and "\n" not in said and fps[1] in said
    assert not (out / "checkpoint").exists()
    # the CLI: a non-zero exit and the same line
    assert main(["merge", "--campaign", str(toml), "-o", str(out), "-q"]) != 0
