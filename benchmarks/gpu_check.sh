#!/bin/bash
# GPU checks, for a machine with a CUDA device (none of this runs in CI):
#   1. the whole test suite with CUDA present, so that every model built with SB3's default device="auto" trains on
#      the GPU (the CPU-only CI covers none of that), in parallel when pytest-xdist is installed;
#   2. solo throughput on the GPU against one CPU thread of the same machine (benchmarks/throughput.py --quick);
#   3. packs on the GPU, larger than a CPU core can take (benchmarks/packed.py --device cuda);
#   4. whether the same seed gives the same run on the GPU (benchmarks/cuda_determinism.py, default and deterministic).
# Logs go to $OUT (default /tmp/gpu_check). Run from the repository root:  bash benchmarks/gpu_check.sh
# PHASES="tests determinism" picks phases (default: all four); PYTEST_ARGS adds pytest options (e.g. --deselect).
# With the package not installed, put the repository root on PYTHONPATH first. Without psycopg, deselect
# tests/test_zoo.py::test_a_storage_that_never_answers_fails_fast_with_a_clear_error (it needs the driver).
set -u
out=${OUT:-/tmp/gpu_check}
mkdir -p "$out"
export PYTHONUNBUFFERED=1 PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
py=${PYTHON:-python3}
{
  nvidia-smi -L
  $py -c "import torch, sb3_macb; print('torch', torch.__version__, 'cuda', torch.version.cuda, torch.cuda.get_device_name(), 'sb3_macb', sb3_macb.__version__)"
  nproc
} 2>&1 | tee "$out/machine.txt"
phases=${PHASES:-tests throughput packs determinism}
xdist=$($py -c "import xdist" 2>/dev/null && echo "-n ${WORKERS:-8}")
if [[ " $phases " == *" tests "* ]]; then
  echo "== tests (CUDA available: models with device='auto' are on the GPU)"
  timeout "${TEST_TIMEOUT:-240}" $py -m pytest -q -ra $xdist -p no:cacheprovider ${PYTEST_ARGS:-} tests 2>&1 | tee "$out/tests.txt"
fi
if [[ " $phases " == *" throughput "* ]]; then
  echo "== solo throughput, GPU then one CPU thread"
  timeout 90 $py benchmarks/throughput.py --quick --device cuda --rounds 2 --steps 600 --warmup 200 2>&1 | tee "$out/throughput_cuda.txt"
  timeout 90 $py benchmarks/throughput.py --quick --device cpu --rounds 2 --steps 300 --warmup 200 2>&1 | tee "$out/throughput_cpu.txt"
fi
if [[ " $phases " == *" packs "* ]]; then
  echo "== packs on the GPU: issue 11's sizes (8 at 64-64, 3 at 400-300), then large ones"
  timeout 150 $py benchmarks/packed.py --device cuda --rounds 1 --steps-64 300 --steps-400 200 2>&1 | tee "$out/packed_cuda_bars.txt"
  timeout 150 $py benchmarks/packed.py --device cuda --rounds 1 --pack-64 32 --pack-400 12 --steps-64 300 --steps-400 200 \
    2>&1 | tee "$out/packed_cuda.txt"
fi
if [[ " $phases " == *" determinism "* ]]; then
  echo "== the same seed twice on the GPU"
  timeout 120 $py benchmarks/cuda_determinism.py --steps "${DET_STEPS:-600}" 2>&1 | tee "$out/determinism.txt"
  timeout 120 $py benchmarks/cuda_determinism.py --steps "${DET_STEPS:-600}" --deterministic 2>&1 | tee "$out/determinism_strict.txt"
fi
