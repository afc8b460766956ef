#!/usr/bin/env bash
# The speed issue's GPU figures in one call (issue 25), on a lent GPU machine whose image has torch but not
# pyro, emcee or arviz: those travel as wheels in .whl/ (see the device tool's README), bayespinn from the tree.
#   1. `many_networks`: networks x steps per second with 1, 8, 64 and 256 networks batched (bench section);
#   2. `bayespinn coverage --method ensemble --snr 30 --replicates 30 --device cuda`, timed; its records
#      are set beside the CPU modal reference of the same datasets afterwards, on the CPU machine
#      (`python studies/gpu_compare.py`).
# Everything lands in $OUT (default ./gpu-out); the coverage's checkpoint comes back even when cut short.
set -u -o pipefail
OUT=${OUT:-gpu-out}
mkdir -p "$OUT"
if [ -d .whl ]; then
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
        --target /tmp/site .whl/*.whl || exit 1
    export PYTHONPATH=/tmp/site:$PWD
fi
export PYTHONUNBUFFERED=1
COV_LIMIT=${COV_LIMIT:-480}
{
    date -u +%FT%TZ
    nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
    nproc
    python3 -c "import torch, numpy, bayespinn; print('torch', torch.__version__, 'numpy', numpy.__version__, 'bayespinn', bayespinn.__version__)"
} 2>&1 | tee "$OUT/machine.txt"
git rev-parse HEAD 2>/dev/null >>"$OUT/machine.txt"

if [ -z "${SKIP_MANY:-}" ]; then
echo "== many_networks"
timeout 90 python3 - "$OUT/many_networks.json" <<'EOF'
import json, sys
from bayespinn.pinn.bench import bench_many_networks
res = bench_many_networks(device="cuda")
json.dump(res, open(sys.argv[1], "w"), indent=2)
for r in res["rows"]:
    print(r)
EOF
fi

echo "== coverage (limit ${COV_LIMIT} s)"
start=$(date +%s.%N)
timeout "$COV_LIMIT" python3 -m bayespinn coverage --method ensemble --snr 30 --replicates 30 \
    --device cuda --out "$OUT/ensemble-cuda-snr30.json" 2>&1 | grep -v "it/s]" | tail -40
rc=${PIPESTATUS[0]}
end=$(date +%s.%N)
echo "coverage rc=$rc wall_s=$(python3 -c "print(round($end - $start, 1))")" | tee -a "$OUT/machine.txt"
ls -la "$OUT"
