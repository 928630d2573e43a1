"""The ``rspiv`` command. Each sub-command lives in its own module with a ``register``
function that adds its parser; this module only assembles them and maps errors to exit codes.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import warnings

from rspiv import __version__
from rspiv.errors import RspivError

# Sub-command modules, in the order they appear in ``rspiv --help``.
_COMMANDS: list[str] = [
    # "rspiv.cli.<name>" modules are appended here by each feature.
    "rspiv.cli.mapping",
    "rspiv.cli.calibrate",
    "rspiv.cli.check",
    "rspiv.cli.piv",
    "rspiv.cli.compare",
    "rspiv.cli.compare_profile",
    "rspiv.cli.ptv",
    "rspiv.cli.correct_vectors",
    "rspiv.cli.statistics",
    "rspiv.cli.dewarp",
    "rspiv.cli.wall",
    "rspiv.cli.init",
    "rspiv.cli.process",
    "rspiv.cli.merge",
    "rspiv.cli.synth",
    "rspiv.cli.demo",
]


def build_parser() -> argparse.ArgumentParser:

    parser = argparse.ArgumentParser(
        prog="rspiv",
        description="Large-sensor PIV with lens-distortion correction.",
    )
    parser.add_argument("--version", action="version", version=f"rspiv {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in _COMMANDS:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``rspiv`` command; returns the exit code."""

    parser = build_parser()
    args = parser.parse_args(argv)
    # a warning shown on the terminal is one line of the command, as its errors (not Python's
    # two lines with the source line that raised it); recorded warnings are not formatted
    fmt = warnings.formatwarning
    warnings.formatwarning = lambda message, *_a, **_k: (
        f"rspiv {args.command}: warning: {message}\n"
    )
    try:
        return int(args.func(args) or 0)
    except (RspivError, ValueError, OSError) as exc:
        print(f"rspiv {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"rspiv {args.command}: interrupted", file=sys.stderr)
        return 130
    finally:
        warnings.formatwarning = fmt


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
