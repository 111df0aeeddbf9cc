#!/usr/bin/env bash
# Builds the `opal` Python package into a fresh venv under the cargo target folder (the way a
# user installs it: `pip install ./crates/opal-py`), builds the `opal` CLI in the same release
# profile, and runs the pytest suite (tests/), which compares the two bit for bit.
# Arguments are passed to `cargo build` of the CLI (e.g. --locked). Exit status: pytest's.
# Needs python3 (≥ 3.9, with venv and pip) and network access to PyPI (maturin, numpy, pytest).
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
root="$(cd "$here/../.." && pwd)"
target="${CARGO_TARGET_DIR:-$root/target}"
venv="$target/opal-py-venv"
py="${PYTHON:-python3}"
t0=$(date +%s)
rm -rf "$venv"
"$py" -m venv "$venv"
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check "$here" pytest numpy
t1=$(date +%s)
cargo build --release --bin opal "$@"
t2=$(date +%s)
cd "$here"
status=0
OPAL_CLI="$target/release/opal" "$venv/bin/python" -m pytest -q -p no:cacheprovider tests || status=$?
t3=$(date +%s)
echo "opal-py: pip install $((t1 - t0)) s, CLI build $((t2 - t1)) s, pytest $((t3 - t2)) s" >&2
exit $status
