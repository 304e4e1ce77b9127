#!/usr/bin/env bash
# Measure a GPU machine for the training engine's targets (bench/gpu_check.py says what), from a
# bare start: where the project or Polars is missing, install them from wheels carried in
# $GPU_CHECK_WHEELS (default .whl: polars and polars-runtime-32, downloaded with
# `pip download --no-deps --only-binary=:all: --python-version 3.12 --platform
# manylinux_2_17_x86_64 polars==V polars-runtime-32==V`) and from this checkout, with no network,
# into $GPU_CHECK_SITE; then run bench/gpu_check.py with the arguments given. The table of the
# target figures comes last.
#
#   bench/gpu_check.sh                       # CUDA, about 6-7 minutes
#   bench/gpu_check.sh build                 # bench/bench_build.py instead, on every core: the
#                                            # six 15-minute recordings (synth, then the build;
#                                            # issue 52's 16-core target)
#   bench/gpu_check.sh --device cpu --recordings 1 --minutes 0.4 --epochs 1 --batch-size 8 \
#       --bench-sizes 8 --steps 1 --fast    # the CPU, a tiny input (tests/test_bench_gpu_check.py)
set -euo pipefail
cd "$(dirname "$0")/.."
python=${PYTHON:-python3}
if ! "$python" -c "import polars, ngsim_cli" 2>/dev/null || ! command -v aigem >/dev/null; then
    site=${GPU_CHECK_SITE:-/tmp/gpu_check_site}
    wheels=${GPU_CHECK_WHEELS:-.whl}
    install=("$python" -m pip install -q --no-index --no-deps --no-compile --target "$site")
    if ! "$python" -c "import polars" 2>/dev/null; then
        "${install[@]}" "$wheels"/*.whl
    fi
    "${install[@]}" --no-build-isolation .
    export PYTHONPATH="$site${PYTHONPATH:+:$PYTHONPATH}"
    export PATH="$site/bin:$PATH"
fi
export PYTHONUNBUFFERED=1
if [[ "${1:-}" == build ]]; then
    shift
    exec "$python" bench/bench_build.py --format txt --against none "$@"
fi
exec "$python" bench/gpu_check.py "$@"
