#!/usr/bin/env bash
# Issue 27's whole GPU check in one call of a lent machine (torch + CUDA there, no internet).
# From the project root, with the wheels of /work/shared/gpu/fetch_wheels.sh carried in .whl/:
#   benchmarks/gpu_session.sh OUT
# Phases, each under its own time limit (T_CHECK, T_K, T_SHIP, T_EVAL, T_SIZES, T_TESTS, T_SMOKE) so
# that one hang loses only itself: the timings of gpu_check.py (the Must-show numbers), host
# syncs and kernels per step, the ship's ring passes and where a taxi step's time goes, more
# sizes, then every registered configuration (gpu_extra.py smoke) beside the device tests.
# About 10 minutes in all: with a machine's start, most of a 15-minute lease.
# Everything printed goes to OUT/log.txt; each part writes its JSON under OUT.
set -u
out=${1:-gpu_out}
mkdir -p "$out"/k "$out"/sizes "$out"/smoke "$out"/eval
export PYTHONUNBUFFERED=1 RL_LOGGING_LEVEL=WARNING
log="$out/log.txt"
if ! python3 -c "import tensordict, torchrl" 2>/dev/null; then
  python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
  export PYTHONPATH=/tmp/site
fi
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH}
{
  date -u
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
  python3 -c "import torch, tensordict, torchrl; print(torch.__version__, tensordict.__version__, torchrl.__version__, torch.cuda.get_device_name(0))"
} 2>&1 | tee -a "$log"
phase() {  # phase SECONDS NAME COMMAND...
  local limit=$1 name=$2
  shift 2
  echo "== $name ($(date -u +%T))" | tee -a "$log"
  timeout "$limit" "$@" 2>&1 | tee -a "$log"
  echo "== $name exit ${PIPESTATUS[0]} ($(date -u +%T))" | tee -a "$log"
}
x="python3 benchmarks/gpu_extra.py --device cuda --seconds 1"
phase "${T_CHECK:-120}" check python3 benchmarks/gpu_check.py --device cuda \
  --parts equal,taxi1,taxi,threshold,threshold64 --out "$out"
phase "${T_K:-60}" syncs-kernels $x --parts syncs,kernels --out "$out/k"
phase "${T_SHIP:-70}" ship-breakdown $x --parts ship,breakdown --out "$out/sizes"
phase "${T_EVAL:-60}" evaluation $x --parts evaluation --out "$out/eval"
phase "${T_SIZES:-60}" sizes $x --parts sizes --pairs taxi/maxq-q,small-agv/har \
  --shapes 10x512,100x2048 --out "$out/sizes"
# correctness, side by side (timings no longer matter)
timeout "${T_TESTS:-150}" python3 -m pytest -q -rf -p no:cacheprovider -n 4 tests/test_device.py \
  tests/test_cuda_graph.py tests/test_any_device.py >"$out/pytest.txt" 2>&1 &
phase "${T_SMOKE:-150}" smoke python3 benchmarks/gpu_extra.py --parts smoke --out "$out/smoke"
wait
tail -5 "$out/pytest.txt" | tee -a "$log"
