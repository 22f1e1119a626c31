#!/usr/bin/env bash
# The device check in one command.
#
#   benchmarks/gpu_check.sh fetch     (here, with network) downloads into .whl/ the wheels
#                                     that the GPU machine's image lacks (Python 3.12)
#   benchmarks/gpu_check.sh [ARGS]    (on the GPU machine) installs them into /tmp/site and
#                                     runs benchmarks/gpu_check.py ARGS, its log also in $OUT
set -euo pipefail
cd "$(dirname "$0")/.."
WHEELS="netCDF4==1.7.2 cftime==1.6.6.1 tomli_w==1.2.0"
if [ "${1:-}" = fetch ]; then
    python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
        --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
        --platform manylinux1_x86_64 -d .whl $WHEELS
    exit
fi
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH="$PWD/src:/tmp/site" PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
log="${OUT:-/tmp}/gpu_check.log"
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader || true
python3 benchmarks/gpu_check.py "$@" 2>&1 | tee "$log"
