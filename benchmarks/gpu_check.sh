#!/usr/bin/env bash
# The issue-27 GPU check (benchmarks/gpu_check.py), on a GPU machine without internet.
# From the project root:  benchmarks/gpu_check.sh OUT [--quick] [--parts ...]
# Wheels the machine lacks (tensordict, torchrl, ...) are carried in .whl/ (fetched here with
# /work/shared/gpu/fetch_wheels.sh .whl; .whl/ and .site/ are in .git/info/exclude) and
# installed into .site/ first. Results: OUT/gpu_check.json (one JSON line each on stdout).
set -eu
out=${1:-gpu_out}
shift || true
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH}
if ! python3 -c "import tensordict" 2>/dev/null; then
  python3 -m pip install -q --no-index --no-deps --no-compile --target .site .whl/*.whl
  export PYTHONPATH=$PWD/.site:$PYTHONPATH
fi
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader || true
python3 benchmarks/gpu_check.py --device cuda --out "$out" "$@"
