#!/usr/bin/env bash
# Second GPU call of 2026-11-27 (after gpu_session.sh found the capture refusals): the
# configurations that failed or were not reached, the ship's ring passes, where a taxi step's
# time goes at 1000 x 1024, the threshold runs, host syncs, and the device tests beside.
#   benchmarks/gpu_recheck.sh OUT      (wheels carried in .whl/, as gpu_session.sh)
set -u
out=${1:-gpu_out}
mkdir -p "$out"/a "$out"/smoke
export PYTHONUNBUFFERED=1 RL_LOGGING_LEVEL=WARNING
log="$out/log.txt"
if ! python3 -c "import tensordict, torchrl" 2>/dev/null; then
  python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
  export PYTHONPATH=/tmp/site
fi
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH}
phase() {  # phase SECONDS NAME COMMAND...
  local limit=$1 name=$2
  shift 2
  echo "== $name ($(date -u +%T))" | tee -a "$log"
  timeout "$limit" "$@" 2>&1 | tee -a "$log"
  echo "== $name exit ${PIPESTATUS[0]} ($(date -u +%T))" | tee -a "$log"
}
x="python3 benchmarks/gpu_extra.py --device cuda --seconds 1"
phase 40 syncs $x --parts syncs --out "$out/a"
phase 50 ship $x --parts ship --out "$out/a"
phase 40 small-agv $x --parts sizes --pairs small-agv/har,four-agv/cooperative --shapes 1x1,10x512 --out "$out/a"
phase 30 breakdown $x --parts breakdown --out "$out/a"
phase 50 check python3 benchmarks/gpu_check.py --device cuda --parts taxi1,threshold,threshold64 --out "$out"
timeout 110 python3 -m pytest -q -rf -p no:cacheprovider -n 4 tests/test_device.py \
  tests/test_cuda_graph.py tests/test_any_device.py >"$out/pytest.txt" 2>&1 &
phase 100 smoke python3 benchmarks/gpu_extra.py --parts smoke --out "$out/smoke" --pairs "$PAIRS"
wait
tail -8 "$out/pytest.txt" | tee -a "$log"
