"""The package imports, exposes its version and typed exceptions, and the command runs."""

import subprocess
import sys

import rspiv


def test_version_and_exceptions():
    assert isinstance(rspiv.__version__, str) and rspiv.__version__.count(".") == 2
    assert issubclass(rspiv.InvalidInputError, ValueError)
    assert issubclass(rspiv.InvalidInputError, rspiv.RspivError)


def test_cli_help_and_unknown_command():
    ok = subprocess.run([sys.executable, "-m", "rspiv", "--help"], capture_output=True, text=True)
    assert ok.returncode == 0 and "rspiv" in ok.stdout
    bad = subprocess.run(
        [sys.executable, "-m", "rspiv", "no-such-command"], capture_output=True, text=True
    )
    assert bad.returncode != 0
