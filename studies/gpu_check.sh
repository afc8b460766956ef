#!/usr/bin/env bash
# The speed issue's GPU figures in one call (issue 25), on a lent GPU machine whose image has torch but not
# pyro, emcee or arviz: those travel as wheels in .whl/ (see the device tool's README), bayespinn from the tree.
#   1. `many_networks`: networks x steps per second with 1, 8, 64 and 256 networks batched (bench section);
#   2. `bayespinn coverage --method ensemble --snr 30 --replicates 30 --device cuda`, timed; its records
#      are set beside the CPU modal reference of the same datasets afterwards, on the CPU machine
#      (`python studies/gpu_compare.py`);
#   3. with the time left (TOTAL_LIMIT s from the start), the same study extended to 100 replicates by
#      --resume in steps of EXTEND_STEP replicates, each a batch checkpointed in the study file, so that a
#      step cut off by the limit loses only itself (ensemble-cuda-snr30-r100.json).
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
TOTAL_LIMIT=${TOTAL_LIMIT:-560}
EXTEND_STEP=${EXTEND_STEP:-20}
t_start=$(date +%s)
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
from bayespinn.pinn.bench_networks import bench_many_networks
res = bench_many_networks(device="cuda")
json.dump(res, open(sys.argv[1], "w"), indent=2)
for r in res["rows"]:
    print(r)
EOF
fi

rc=skipped
if [ -z "${SKIP_COV:-}" ]; then
echo "== coverage (limit ${COV_LIMIT} s)"
start=$(date +%s.%N)
timeout "$COV_LIMIT" python3 -m bayespinn coverage --method ensemble --snr 30 --replicates 30 \
    --device cuda --out "$OUT/ensemble-cuda-snr30.json" 2>&1 | grep -v "it/s]" | tail -40
rc=${PIPESTATUS[0]}
end=$(date +%s.%N)
echo "coverage rc=$rc wall_s=$(python3 -c "print(round($end - $start, 1))")" | tee -a "$OUT/machine.txt"
fi

# EXTEND_FROM=reports/gpu/ensemble-cuda-snr30-r50.json SKIP_MANY=1 SKIP_COV=1: go on from a study file
# of an earlier session instead (its replicates keep the commit that computed them)
if [ -n "${EXTEND_FROM:-}" ]; then
    cp "$EXTEND_FROM" "$OUT/ensemble-cuda-snr30-r100.json"
elif [ "$rc" = 0 ]; then
    cp "$OUT/ensemble-cuda-snr30.json" "$OUT/ensemble-cuda-snr30-r100.json"
fi
if [ -f "$OUT/ensemble-cuda-snr30-r100.json" ] && [ -z "${SKIP_EXTEND:-}" ]; then
    n=$(python3 -c "import json, sys; print(json.load(open(sys.argv[1]))['replicates'])" \
        "$OUT/ensemble-cuda-snr30-r100.json")
    while [ "$n" -lt 100 ]; do
        next=$((n + EXTEND_STEP)); [ "$next" -gt 100 ] && next=100
        left=$((TOTAL_LIMIT - ($(date +%s) - t_start)))
        [ "$left" -lt 60 ] && { echo "extension stops at $n replicates: ${left} s left"; break; }
        echo "== extend to $next replicates (limit ${left} s)"
        s0=$(date +%s.%N)
        timeout "$left" python3 -m bayespinn coverage --method ensemble --snr 30 --replicates "$next" \
            --device cuda --resume --quiet --out "$OUT/ensemble-cuda-snr30-r100.json" 2>&1 | tail -5
        r=${PIPESTATUS[0]}
        e=$(date +%s.%N)
        echo "extend $n->$next rc=$r wall_s=$(python3 -c "print(round($e - $s0, 1))")" | tee -a "$OUT/machine.txt"
        [ "$r" = 0 ] || break
        n=$next
    done
fi
ls -la "$OUT"
