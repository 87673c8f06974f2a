#!/usr/bin/env bash
# The GPU training runs behind the shipped weights and the GPU rows of benchmarks/RESULTS.md, as they
# ran on a lent machine (one H100, 16 cores, no network; see benchmarks/gpu/README.md).
# Phases, one per call of a short lease: setup | render | launch | status | collect OUTDIR
#   setup   unpack EGL libraries (.gl/*.deb) and the wheels the image lacks (.whl/) into /tmp/site
#   render  40 000 training views (seed 1) + the 1 000-view test set (seed 100), 14 processes
#   launch  three trainings at once, detached (setsid), each stopping itself by TIME_LIMIT minutes
#   status  epochs so far (metrics.csv tails)
#   collect exported checkpoints, metrics and the parallel-vgg19 evaluation report into OUTDIR
#           (a short call of its own, as soon as the runs end: see README.md)
set -euo pipefail
cd "$(dirname "$0")/../.."
export PYTHONPATH=/tmp/site:$PWD MUJOCO_GL=egl PYTHONUNBUFFERED=1
DATA=${DATA:-/tmp/hp/data} RUNS=${RUNS:-/tmp/hp/runs} TIME_LIMIT=${TIME_LIMIT:-16}
hp() { python3 -m hybridpose "$@"; }
case "${1:-}" in
setup)
    for f in .gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
    nvidia-smi -L
    python3 -c "import torch, cv2, mujoco, kornia; print('torch', torch.__version__, torch.cuda.is_available(), 'cv2', cv2.__version__, 'mujoco', mujoco.__version__)"
    ;;
render)
    common=(--object truss --kind random --size 640x480 --in-view --sun-cone 40 --sun-range 0.7,1.3 --workers 14)
    hp render "${common[@]}" --count 1000 --seed 100 --out "$DATA/test" 2>&1 | tail -1
    hp render "${common[@]}" --count 40000 --seed 1 --out "$DATA/train" 2>&1 | tail -1
    du -sh "$DATA"/*
    ;;
launch)
    mkdir -p "$RUNS"
    train=(train --data "$DATA/train" --seed 0 --val-fraction 0.05 --patience 0 --time-limit "$TIME_LIMIT")
    # each run exports its inference checkpoint as soon as it ends, so `collect` only copies
    for spec in "default 24" "keypoints 20"; do
        set -- $spec
        setsid nohup bash -c "python3 -m hybridpose ${train[*]} --model $1 --epochs $2 --batch 32 --workers 4 \
            --out $RUNS/$1 > $RUNS/$1.log 2>&1 && python3 -m hybridpose export --checkpoint $RUNS/$1/best.pt \
            --out $RUNS/$1.pt >> $RUNS/$1.log 2>&1" > /dev/null 2>&1 &
    done
    setsid nohup bash -c "python3 -m hybridpose ${train[*]} --model parallel-vgg19 --epochs 10 --batch 32 --workers 6 \
        --amp --out $RUNS/pvgg > $RUNS/pvgg.log 2>&1 && \
        python3 -m hybridpose eval --checkpoint $RUNS/pvgg/best.pt --data $DATA/test --out $RUNS/pvgg_eval \
        > $RUNS/pvgg_eval.log 2>&1" > /dev/null 2>&1 &
    sleep 60
    tail -n 3 "$RUNS"/*.log
    nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv
    ;;
status)
    for r in default keypoints pvgg; do echo "== $r"; tail -n 4 "$RUNS/$r/metrics.csv" 2>/dev/null || tail -c 600 "$RUNS/$r.log"; done
    nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv,noheader
    uptime
    ;;
collect)
    out=${2:?collect OUTDIR}
    for r in default keypoints; do
        cp "$RUNS/$r.pt" "$out/" || echo "$r: not exported yet"
        cp "$RUNS/$r/metrics.csv" "$out/$r.metrics.csv" || true
    done
    cp "$RUNS/pvgg/metrics.csv" "$out/pvgg.metrics.csv" || true
    tar -C "$RUNS" -czf "$out/logs_and_pvgg_eval.tgz" $(cd "$RUNS" && ls -d *.log pvgg_eval 2>/dev/null)
    ls -la "$out"
    ;;
*)
    echo "usage: $0 setup|render|launch|status|collect OUTDIR" >&2
    exit 2
    ;;
esac
