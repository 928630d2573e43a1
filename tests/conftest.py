"""Shared pytest fixtures."""

from __future__ import annotations

import os
import pathlib
import shutil
import subprocess

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"


@pytest.fixture(scope="session")
def repo_root() -> pathlib.Path:
    return REPO


@pytest.fixture
def rng():
    import numpy as np

    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def engine() -> str:
    """Path of the standalone ``rspiv-engine`` binary, built (or brought up to date) by cargo;
    without cargo, an ``rspiv-engine`` on the PATH.

    Built by the command CI runs before pytest (``cargo test --workspace --exclude rspiv-py``,
    here with ``--no-run``): the same profile (``[profile.test]``), features and units, so in CI
    the binary is already there. A plain ``cargo build -p rspiv-engine`` resolves other features
    (``either/use_std``, ``serde/alloc``) and rebuilt every core crate (172 s of the suite on 2
    cores); ``cargo build --tests --bins`` builds with the dev profile, not the test profile
    ``cargo test`` uses, and rebuilt every crate's unit tests (221-264 s of CI's suite once the
    test profile differed)."""
    cargo = shutil.which("cargo")
    if cargo is not None:
        cmd = [cargo, "test", "-q", "--no-run", "--workspace", "--exclude", "rspiv-py"]
        subprocess.run(cmd, cwd=REPO, check=True)
        return str(REPO / "target" / "debug" / "rspiv-engine")
    exe = shutil.which("rspiv-engine")
    if exe is None:
        pytest.fail("neither cargo nor an installed rspiv-engine is available")
    return exe


# ---------------------------------------------------------------------------- skips
# CI (scripts/test.sh sets RSPIV_STRICT_SKIPS=1) tests what it claims: a test that skips fails
# the run unless it was skipped on purpose, i.e. its reason starts with "on purpose:" (for a
# skip that is right on every machine, e.g. a platform-only check). Every reason is printed.
ON_PURPOSE = "on purpose:"
_skips: list[tuple[str, str, bool]] = []  # (test id, reason, on purpose)


def _skip_reason(report) -> str:
    lr = report.longrepr
    text = lr[2] if isinstance(lr, tuple) and len(lr) == 3 else str(lr)
    return text.removeprefix("Skipped: ").strip()


def pytest_runtest_logreport(report):
    if report.skipped and not hasattr(report, "wasxfail"):
        reason = _skip_reason(report)
        _skips.append((report.nodeid, reason, reason.startswith(ON_PURPOSE)))


def pytest_terminal_summary(terminalreporter):
    if not _skips:
        return
    terminalreporter.section("skipped tests")
    for nodeid, reason, ok in _skips:
        tag = "on purpose" if ok else "NOT ON PURPOSE"
        terminalreporter.write_line(f"{tag}: {nodeid}: {reason}")
    n_bad = sum(not ok for _, _, ok in _skips)
    if n_bad and os.environ.get("RSPIV_STRICT_SKIPS", "") not in ("", "0"):
        terminalreporter.write_line(
            f"RSPIV_STRICT_SKIPS: {n_bad} test(s) skipped not on purpose: the run fails"
        )


def pytest_sessionfinish(session, exitstatus):
    strict = os.environ.get("RSPIV_STRICT_SKIPS", "") not in ("", "0")
    bad = [s for s in _skips if not s[2]]
    if strict and bad and session.exitstatus == 0:
        session.exitstatus = 1  # reported by pytest_terminal_summary
