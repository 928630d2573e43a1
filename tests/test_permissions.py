"""Outputs are readable as the user's umask says (issue 11): every file ``rspiv process`` writes
(calibration JSON, NetCDF, CSV, checkpoints, report) has the permissions of any file the user
creates, not the private 0600 of a temporary file; a file replaced keeps its own mode."""

from __future__ import annotations

import os
import stat

import pytest
from rspiv.campaign_config import load_campaign_config
from rspiv.cli import main
from rspiv.outputs import atomic_write_text, creation_mode


@pytest.fixture
def umask_027():
    old = os.umask(0o027)
    try:
        yield 0o640
    finally:
        os.umask(old)


def test_process_writes_files_with_the_umask_mode(tmp_path, umask_027):
    d = tmp_path / "c"
    synth = ["synth", "campaign", str(d), "--pairs", "2", "--scale", "0.1", "--monte-carlo", "0"]
    assert main([*synth, "-q"]) == 0
    cfg = load_campaign_config(d / "campaign.toml")
    cfg.correction.compare_uncorrected = False
    cfg.save(d / "campaign.toml")
    out = tmp_path / "out"
    assert main(["process", str(d / "campaign.toml"), "-q", "-o", str(out)]) == 0
    files = [p for p in out.rglob("*") if p.is_file()]
    kinds = {p.suffix for p in files}
    assert {".json", ".nc", ".csv", ".html"} <= kinds, kinds
    modes = {str(p.relative_to(out)): stat.S_IMODE(p.stat().st_mode) for p in files}
    wrong = {k: oct(m) for k, m in modes.items() if m != umask_027}
    assert not wrong, wrong
    assert stat.S_IMODE((d / "campaign.toml").stat().st_mode) == umask_027


def test_a_replaced_file_keeps_its_mode(tmp_path, umask_027):
    p = tmp_path / "x.txt"
    atomic_write_text(p, "one")
    assert stat.S_IMODE(p.stat().st_mode) == umask_027 == creation_mode(tmp_path / "new")
    p.chmod(0o604)
    atomic_write_text(p, "two")
    assert p.read_text() == "two" and stat.S_IMODE(p.stat().st_mode) == 0o604
    with pytest.raises(FileNotFoundError):
        atomic_write_text(tmp_path / "missing" / "y.txt", "z", make_parents=False)
    assert not list(tmp_path.glob(".*"))  # no temporary file left behind
