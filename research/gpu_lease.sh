#!/usr/bin/env bash
# What one lent GPU runs for issue 44, in one call of the device tool (research record; not
# part of the product). Run from the repository root on the device machine, with the
# torchrl / tensordict / gymnasium / omegaconf / shapely wheels in .whl/ (carried) and $OUT
# the folder that comes back. Stages in the order of their value, each with its own time
# limit, so a slow stage costs only its own figures; everything is written to $OUT as it
# comes:
#   1. the throughput benchmark: eager / compiled / captured at N = 16,384 (the launch-bound
#      size), compiled at 1,048,576 and 4,194,304, with memory per env, host syncs per call
#      and a torch.profiler table at the largest N;
#   2. the gpu preset's PPO run (12M frames), its TensorBoard events and newest checkpoint;
#   3. the tests that take the device fixture (python -m pytest --device cuda --device-only),
#      in the time left.
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

stage "throughput, N = 16,384"
TQDM_DISABLE=1 timeout 150 python3 -m benchmarks.throughput --device cuda --sizes 16384 \
    --modes eager compiled cudagraphs --paths step step_and_maybe_reset --reset-in-step on \
    2>&1 | tee "$OUT/throughput_16k.txt"
stage "throughput, N = 1M and 4M"
TQDM_DISABLE=1 timeout 140 python3 -m benchmarks.throughput --device cuda --sizes 1048576 4194304 \
    --modes compiled --paths step step_and_maybe_reset --reset-in-step on \
    --profile 4194304 --profile-out "$OUT/profile_4M.txt" \
    2>&1 | tee "$OUT/throughput_large.txt"

stage "the gpu preset"
timeout 170 python3 -m trainers.ppo --preset gpu logger.log_dir=/tmp/runs \
    > "$OUT/ppo_gpu.log" 2>&1
echo "ppo exit $?"; tail -c 600 "$OUT/ppo_gpu.log"; echo
(cd /tmp/runs/gpu && tar -cf "$OUT/run_gpu.tar" events.* config.* $(ls -t checkpoint_*.pt | head -1)) 2>&1 | tail -2

LEFT=$(( BUDGET - ($(date +%s) - T0) ))
stage "device tests ($LEFT s left)"
if [ "$LEFT" -gt 40 ]; then
    timeout "$LEFT" python3 -m pytest -q -o addopts="-ra" -p no:cacheprovider --device cuda \
        --device-only -n 8 tests/test_cuda.py tests/test_env.py tests/test_lockstep.py \
        tests/test_step.py tests/test_brake.py 2>&1 | tee "$OUT/tests.txt" | tail -40
fi
stage done
