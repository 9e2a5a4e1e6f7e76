#!/usr/bin/env bash
# What a lent GPU runs for issue 44, in one call of the device tool (research record; not
# part of the product). Run from the repository root on the device machine, with the
# torchrl / tensordict / gymnasium / omegaconf / shapely wheels in .whl/ (carried) and $OUT
# the folder that comes back. Stages in the order of their value, each with its own time
# limit, so a slow stage costs only its own figures; everything is written to $OUT as it
# comes. The second lease (2026-11-28) ran the throughput at 16,384 / 1M / 4M, the first
# gpu preset and the device tests; what it left open comes first now:
#   1. the step captured as a CUDA graph (the env's copies out of the graphs' memory) against
#      the compiled step, at 4,096 and 16,384 envs, with the collector path;
#   2. the gpu preset as it is now (fast's batch from 4,096 envs): 12M frames, its events and
#      final checkpoint (gzipped, split under the 16 MB a file that comes back);
#   3. the tests that take the device fixture, the xfailed ones run (--runxfail: the sync
#      test's message names the lines the syncs come from), in the time left.
# The wheels (the device has torch 2.11 but none of these), fetched here before the lease:
#   for p in torchrl==0.14.1 tensordict==0.14.3 hoptorch==0.1.4 pyvers==0.2.3 orjson \
#       importlib_metadata gymnasium==1.4.0 farama-notifications omegaconf==2.4.0 shapely==2.2.0
#   do python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
#       --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 \
#       --platform manylinux2014_x86_64 --platform any -d .whl $p; done
# Call: run(command="bash research/gpu_lease.sh", carry=[".whl"], timeout_s=600).
set -u
T0=$(date +%s)
BUDGET=${BUDGET:-575}
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
stage() { echo "=== $1 at $(( $(date +%s) - T0 )) s"; }
stage setup
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
python3 -c "import torch, torchrl, tensordict; print('torch', torch.__version__, 'torchrl', \
torchrl.__version__, 'tensordict', tensordict.__version__, torch.cuda.get_device_name())"

stage "throughput, captured against compiled"
TQDM_DISABLE=1 timeout 200 python3 -m benchmarks.throughput --device cuda --sizes 4096 16384 \
    --modes compiled cudagraphs --paths step step_and_maybe_reset collector \
    --reset-in-step on 2>&1 | tee "$OUT/throughput.txt"

stage "the gpu preset"
timeout 200 python3 -m trainers.ppo --preset gpu logger.log_dir=/tmp/runs \
    > "$OUT/ppo_gpu.log" 2>&1
echo "ppo exit $?"; tail -c 600 "$OUT/ppo_gpu.log"; echo
(cd /tmp/runs/gpu && tar -czf /tmp/run.tgz events.* $(ls -t checkpoint_*.pt | head -1) \
    && split -b 15M /tmp/run.tgz "$OUT/run_gpu.tgz.") 2>&1 | tail -2

LEFT=$(( BUDGET - ($(date +%s) - T0) ))
stage "device tests ($LEFT s left)"
if [ "$LEFT" -gt 40 ]; then
    timeout "$LEFT" python3 -m pytest -q -o addopts="-ra" -p no:cacheprovider -p no:benchmark \
        --device cuda --device-only --runxfail -n 8 tests/test_cuda.py tests/test_env.py \
        tests/test_lockstep.py tests/test_step.py tests/test_brake.py 2>&1 \
        | grep -v "DEBUG" | tee "$OUT/tests.txt" | tail -40
fi
stage done
