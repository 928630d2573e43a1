#!/usr/bin/env bash
# Every test of the project, from a fresh clone of a fresh machine (the README's test command):
# formatting and lints, the Rust unit tests of the cores, the Python package built and installed
# as the README installs it, and pytest.
set -euo pipefail
cd "$(dirname "$0")/.."

export CARGO_TERM_COLOR=never
python3 -m pip install --quiet --upgrade pip "maturin>=1.9.4,<2"

echo "== cargo fmt"
cargo fmt --all -- --check
echo "== cargo clippy"
cargo clippy --workspace --all-targets --locked -- -D warnings
echo "== cargo test (cores and CLI)"
cargo test --workspace --exclude rspiv-py --locked

echo "== pip install .[test,dask,bench,davis]"
# Every extra the tests use: Dask for the scale-out tests, OpenCV for the remap comparison.
python3 -m pip install --quiet ".[test,dask,bench,davis]"
echo "== ruff"
python3 -m ruff check python tests benches
echo "== pytest"
# Run from tests/ so that the installed package, not the source tree, is imported.
# A test that skips fails the run unless its reason starts with "on purpose:" (tests/conftest.py).
# Two pytest-xdist workers, one test module each at a time (--dist loadfile: a module's campaign
# fixtures run once): the suite is mostly single-threaded Python between its Rust calls, so two
# workers on 2 cores take about 10 minutes where one took 15-18.
cd tests
RSPIV_STRICT_SKIPS=1 python3 -m pytest -q -p no:cacheprovider -n 2 --dist loadfile --durations=15 .
