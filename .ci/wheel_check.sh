#!/usr/bin/env bash
# The package as a user installs it: build the wheel, install it into a fresh venv (torch first, deepod
# with --no-deps), then from an empty folder run `scart-bench run --detectors all` on the quick default.
# Also checks that the wheel ships the scenario files and installs no top-level `benchmark` module.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-python3}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
$PY -m venv "$work/venv"
bin="$work/venv/bin"
"$bin/pip" install --quiet --upgrade pip
"$bin/pip" install --quiet torch==2.13.0
rm -rf build  # a stale build/lib would ship modules that no longer exist
"$bin/pip" wheel --quiet --no-deps . -w "$work/dist"
rm -rf build
wheel=$(ls "$work"/dist/scart_bench-*.whl)
"$bin/pip" install --quiet "${wheel}[all]"
"$bin/pip" install --quiet --no-deps deepod==0.4.1
mkdir "$work/empty"
cd "$work/empty"
if "$bin/python" -c "import benchmark" 2>/dev/null; then
  echo "wheel check: a top-level 'benchmark' module is importable" >&2; exit 1
fi
"$bin/python" - "$OLDPWD" <<'PY'
import sys
from importlib import resources
from pathlib import Path

# every package of the source tree is in the installed wheel (the packages list is explicit)
src = Path(sys.argv[1])
wanted = {"scart_bench"} | {
    "scart_bench." + ".".join(p.parent.relative_to(src).parts)
    for top in ("benchmark", "detectors", "generator", "reports", "data") for p in (src / top).rglob("__init__.py")} | {
    "scart_bench." + ".".join(p.parent.relative_to(src / "scart_bench").parts)
    for p in (src / "scart_bench").rglob("__init__.py") if p.parent != src / "scart_bench"}
import importlib.util
missing = sorted(m for m in wanted if importlib.util.find_spec(m) is None)
assert not missing, f"packages missing from the wheel: {missing} (add them to pyproject's packages list)"
print(f"wheel check: {len(wanted)} packages installed")

names = sorted(p.name for p in resources.files("scart_bench.data").joinpath("scenarios").iterdir())
assert "paper.toml" in names and "quick.toml" in names and "gps_spoof.toml" in names, names
print(f"wheel check: {len(names)} scenario files shipped")
PY
"$bin/scart-bench" run --detectors all --jobs 2
test -f runs/quick-seed0/metrics.csv
echo "wheel check: OK ($wheel)"
