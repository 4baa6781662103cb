#!/bin/bash
# The Spider at the learning issue's protocol (SCORE, 3 seeds x 500k steps, benchmarks/learning.py)
# on a GPU machine that has jax, flax and optax but no network (docs/learning.md, entry 17).
# Before, on a machine with PyPI: download the missing wheels for that machine's Python into .whl/:
#   pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
#     --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 -d .whl \
#     mujoco==4.0.0 mujoco-core==4.0.0 mujoco-studio==4.0.0 mujoco-mjx==3.17.0 glfw pyopengl \
#     trimesh tyro==1.0.17 docstring-parser typeguard websockets
# Then run this from the repository root there. BUDGET (seconds, default 540) bounds the whole
# invocation; what remains after the default run goes to the same run with the LayerNorm critic.
# Results: /tmp/bench_*, /tmp/work_* and, where ${OUT:-/tmp} is set, <name>.tgz and logs in ${OUT:-/tmp}.
T0=$(date +%s)
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 3
# no MUJOCO_GL: the machine has no libEGL, and nothing is rendered here
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
nvidia-smi -L; nproc
python3 -c "import jax, flax, mujoco; from mujoco import mjx; import optax, orbax.checkpoint as oc, chex; print(jax.__version__, jax.devices(), flax.__version__, optax.__version__, mujoco.__version__)" || exit 4
pack() {  # $1 name, $2 work dir, $3 bench dir
  (cd /tmp && tar czf ${OUT:-/tmp}/$1.tgz --exclude='checkpoints' $(basename $2) $(basename $3) 2>/dev/null)
  ls -la ${OUT:-/tmp}
}
BUDGET=${BUDGET:-540}
stamp() { while IFS= read -r l; do echo "[$(( $(date +%s) - T0 ))s] $l"; done; }
left() { echo $(( BUDGET - ($(date +%s) - T0) )); }
timeout $(left) python3 benchmarks/learning.py --envs spider --spider-seeds 3 --spider-env-steps 500000 \
  --no-gif --out /tmp/bench_default --work-dir /tmp/work_default 2>&1 | grep --line-buffered -v -i warn | stamp | tee /tmp/bench_default.log
echo "default done at $(( $(date +%s) - T0 )) s"
cp /tmp/bench_default.log /tmp/bench_default/ 2>/dev/null; cp /tmp/bench_default.log ${OUT:-/tmp}/
pack default /tmp/work_default /tmp/bench_default
L=$(left); echo "left for layernorm: $L s"
if [ $L -gt 90 ]; then
  timeout $L python3 benchmarks/learning.py --envs spider --spider-seeds 3 --spider-env-steps 500000 \
    --no-gif --base.score.critic.layer-norm --out /tmp/bench_ln --work-dir /tmp/work_ln 2>&1 | grep --line-buffered -v -i warn | stamp | tee /tmp/bench_ln.log
  mkdir -p /tmp/bench_ln; cp /tmp/bench_ln.log /tmp/bench_ln/; cp /tmp/bench_ln.log ${OUT:-/tmp}/
  pack layernorm /tmp/work_ln /tmp/bench_ln
fi
echo "all done at $(( $(date +%s) - T0 )) s"
