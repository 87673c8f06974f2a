#!/usr/bin/env bash
# The GPU training runs behind the shipped weights and the GPU rows of benchmarks/RESULTS.md, as they
# ran on a lent machine (one H100, 16 cores, no network; see benchmarks/gpu/README.md).
# Phases, one per call of a short lease: start (= setup render launch) | status | collect OUTDIR
#   setup   unpack EGL libraries (.gl/*.deb) and the wheels the image lacks (.whl/) into /tmp/site
#   render  TRAIN_COUNT training views (seed TRAIN_SEED) + the 1 000-view test set (seed 100), 15 processes
#   launch  three trainings at once, detached (setsid), each stopping itself by TIME_LIMIT minutes:
#           `default` fine-tuned from INIT (a checkpoint carried in .carry/), `keypoints` and
#           `parallel-vgg19` from scratch (the latter evaluated on the test set when it ends)
#   status [OUTDIR]  epochs so far (metrics.csv tails); with OUTDIR also what `collect` copies, so
#           that every keep-warm call brings back what is finished (a lost warm window loses the rest)
#   collect exported checkpoints (split below the 16 MiB a returned file may have), metrics, logs and
#           the parallel-vgg19 evaluation report into OUTDIR (a short call of its own: see README.md)
# The paper's four VGG models: start-vgg (= setup render launch-vgg, then wait-vgg) |
# wait-vgg OUTDIR SECONDS (sleep until SECONDS after the call began, CALL_START in epoch seconds, then
# status and collect-vgg: every call brings back what is done)
#   launch-vgg  vgg16, vgg19, branched-vgg19, parallel-vgg19 at once, detached, from scratch (no ImageNet
#           weights can reach the machine), the paper's loss and Adam 1e-4, bf16, batch 32, 100 epochs
#           planned and TIME_LIMIT minutes allowed; each then evaluated on the GPU on the seed-100 test set,
#           without a prior and with each view's true box as roi (the paper's bounded image)
#   cache-vgg   decode the training views once into $DATA/cache (224 px frames and fixed crops) for
#           all four runs (`--cache-images`; launch-vgg and crop-check run it first); the
#           runs write last.pt every 10 epochs (`--checkpoint-every`: a parallel VGG-19's is 4.6 GB)
#   collect-vgg OUTDIR  metrics, logs and the evaluation reports in one archive (checkpoints of
#           0.5-1.1 GB cannot come back)
set -euo pipefail
cd "$(dirname "$0")/../.."
export CALL_START=${CALL_START:-$(date +%s)}
export PYTHONPATH=/tmp/site:$PWD MUJOCO_GL=egl PYTHONUNBUFFERED=1
DATA=${DATA:-/tmp/hp/data} RUNS=${RUNS:-/tmp/hp/runs} TIME_LIMIT=${TIME_LIMIT:-15}
TRAIN_COUNT=${TRAIN_COUNT:-24000} TRAIN_SEED=${TRAIN_SEED:-4} INIT=${INIT:-.carry/stage4.pt}
hp() { python3 -m hybridpose "$@"; }
phase=${1:-}
if [ "$phase" = start ]; then bash "$0" setup && bash "$0" render && exec bash "$0" launch; fi
if [ "$phase" = start-vgg ]; then
    bash "$0" setup && bash "$0" render && bash "$0" launch-vgg && exec bash "$0" wait-vgg "${2:?start-vgg OUTDIR SECONDS}" "${3:?}"
fi
# which VGG models launch-vgg trains (all four by default, e.g. VGG_RUNS=parallel-vgg19 alone; MODEL@INIT
# trains MODEL with `--vgg-init INIT` in the folder MODEL-INIT, e.g. "vgg19@torchvision vgg19@torch-default" for an
# A/B of the initialisation), the validation share (the paper: an 80/20 split, VAL_FRACTION=0.2), loader workers
# (WORKERS: one number for every run; default 3, 5 for the parallel model when four share the machine) and the
# last.pt interval
read -r -a VGG_RUNS <<< "${VGG_RUNS:-vgg16 vgg19 branched-vgg19 parallel-vgg19}"
VAL_FRACTION=${VAL_FRACTION:-0.05} CHECKPOINT_EVERY=${CHECKPOINT_EVERY:-10}
run_name() { if [[ $1 == *@* ]]; then echo "${1%@*}-${1#*@}"; else echo "$1"; fi; }
RUN_NAMES=(); for spec in "${VGG_RUNS[@]}"; do RUN_NAMES+=("$(run_name "$spec")"); done
case "$phase" in
setup)
    for f in .gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
    nvidia-smi -L
    python3 -c "import torch, cv2, mujoco, kornia; print('torch', torch.__version__, torch.cuda.is_available(), 'cv2', cv2.__version__, 'mujoco', mujoco.__version__)"
    ;;
render)
    common=(--object truss --kind random --size 640x480 --in-view --sun-cone 40 --sun-range 0.7,1.3 --workers 15)
    hp render "${common[@]}" --count 1000 --seed 100 --out "$DATA/test" 2>&1 | tail -1
    hp render "${common[@]}" --count "$TRAIN_COUNT" --seed "$TRAIN_SEED" --out "$DATA/train" 2>&1 | tail -1
    du -sh "$DATA"/*
    ;;
launch)
    mkdir -p "$RUNS"
    train=(train --data "$DATA/train" --seed 0 --val-fraction 0.05 --patience 0)
    # each run exports its inference checkpoint as soon as it ends, so `collect` only copies
    export_after() { echo "&& python3 -m hybridpose export --checkpoint $RUNS/$1/best.pt --out $RUNS/$1.pt >> $RUNS/$1.log 2>&1"; }
    setsid nohup bash -c "python3 -m hybridpose ${train[*]} --time-limit $TIME_LIMIT --model default --epochs 12 --lr 2e-4 --init-from $INIT \
        --batch 32 --workers 6 --out $RUNS/default > $RUNS/default.log 2>&1 $(export_after default)" > /dev/null 2>&1 &
    setsid nohup bash -c "python3 -m hybridpose ${train[*]} --time-limit $TIME_LIMIT --model keypoints --epochs 14 --batch 32 --workers 4 \
        --out $RUNS/keypoints > $RUNS/keypoints.log 2>&1 $(export_after keypoints)" > /dev/null 2>&1 &
    # parallel-vgg19 stops 3 minutes earlier: its evaluation (on the GPU: `eval --device cuda`) follows
    setsid nohup bash -c "python3 -m hybridpose ${train[*]} --time-limit $((TIME_LIMIT - 3)) \
        --model parallel-vgg19 --epochs 10 --batch 32 --workers 5 --amp --out $RUNS/pvgg > $RUNS/pvgg.log 2>&1 && \
        python3 -m hybridpose eval --checkpoint $RUNS/pvgg/best.pt --data $DATA/test --device cuda --out $RUNS/pvgg_eval \
        > $RUNS/pvgg_eval.log 2>&1" > /dev/null 2>&1 &
    sleep 60
    tail -n 3 "$RUNS"/*.log
    nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv
    ;;
cache-vgg)
    # the VGG models' inputs (224 px full frames, fixed crops) decoded once for all four runs
    python3 -c "from hybridpose.datasets.torch_dataset import PoseDataset as P
for crop in (False, True): P('$DATA/train', size=224, crop=crop).cache_images('$DATA/cache', workers=15)"
    ;;
launch-vgg)
    mkdir -p "$RUNS"
    bash "$0" cache-vgg
    declare -A workers=([vgg16]=3 [vgg19]=3 [branched-vgg19]=3 [parallel-vgg19]=5)  # parallel reads each view twice
    for spec in "${VGG_RUNS[@]}"; do
        m=${spec%@*} r=$(run_name "$spec") init=()
        if [[ $spec == *@* ]]; then init=(--vgg-init "${spec#*@}"); fi
        rm -f "$RUNS/$r.done"
        setsid nohup bash -c "python3 -m hybridpose train --model $m ${init[*]} --data $DATA/train --seed 0 \
            --val-fraction $VAL_FRACTION --patience 0 --epochs 100 --batch 32 --amp --workers ${WORKERS:-${workers[$m]}} \
            --time-limit $TIME_LIMIT --out $RUNS/$r --checkpoint-every $CHECKPOINT_EVERY --cache-images $DATA/cache \
            > $RUNS/$r.log 2>&1; python3 -m hybridpose eval --checkpoint $RUNS/$r/best.pt --data $DATA/test --device cuda \
            --out $RUNS/${r}_eval > $RUNS/${r}_eval.log 2>&1; python3 -m hybridpose eval --checkpoint $RUNS/$r/best.pt \
            --data $DATA/test --device cuda --roi truth --out $RUNS/${r}_eval_roi > $RUNS/${r}_eval_roi.log 2>&1; \
            touch $RUNS/$r.done" > /dev/null 2>&1 &
    done
    sleep 45
    tail -n 2 "$RUNS"/*.log
    nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv
    ;;
wait-vgg)
    out=${2:?wait-vgg OUTDIR SECONDS}
    # sleep until SECONDS after the call began, or until every run and its evaluations are done
    deadline=$(( ${CALL_START:-$(date +%s)} + ${3:?} ))
    while [ "$(date +%s)" -lt "$deadline" ]; do
        pending=0
        for m in "${RUN_NAMES[@]}"; do [ -f "$RUNS/$m.done" ] || pending=1; done
        if [ "$pending" = 0 ]; then echo "all runs done"; break; fi
        sleep 5
    done
    for m in "${RUN_NAMES[@]}"; do
        echo "== $m"; tail -n 3 "$RUNS/$m/metrics.csv" 2>/dev/null || tail -c 400 "$RUNS/$m.log" 2>/dev/null || true
        tail -n 2 "$RUNS/${m}_eval.log" 2>/dev/null || true
    done
    nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv,noheader || true
    uptime
    exec bash "$0" collect-vgg "$out"
    ;;
crop-check)
    # the parallel VGG-19 alone for TIME_LIMIT minutes, then evaluated on EVAL_LIMIT test views without a roi
    # (the detected object's crop) and with the true box: one call, what is left of a lease
    out=${2:?crop-check OUTDIR}
    bash "$0" setup && bash "$0" render && bash "$0" cache-vgg
    mkdir -p "$RUNS"
    hp train --model parallel-vgg19 --data "$DATA/train" --seed 0 --val-fraction 0.05 --patience 0 --epochs 100 \
        --batch 32 --amp --workers 14 --time-limit "$TIME_LIMIT" --checkpoint-every 10 --cache-images "$DATA/cache" \
        --out "$RUNS/parallel-vgg19" \
        > "$RUNS/parallel.log" 2>&1 || true
    for roi in none truth; do
        hp eval --checkpoint "$RUNS/parallel-vgg19/best.pt" --data "$DATA/test" --device cuda --limit "${EVAL_LIMIT:-300}" \
            --roi $roi --out "$RUNS/parallel-vgg19_eval_$roi" 2>&1 | tail -1 || true
    done
    tail -n 4 "$RUNS/parallel-vgg19/metrics.csv" || true
    (cd "$RUNS" && tar -czf "$out/crop_check.tgz" parallel.log parallel-vgg19/metrics.csv parallel-vgg19_eval_* || true)
    ls -la "$out"
    ;;
collect-vgg)
    out=${2:?collect-vgg OUTDIR}
    (cd "$RUNS" && find . -maxdepth 2 \( -name '*.log' -o -name metrics.csv -o -name history.json \) -print0 \
        | tar --null -T - -czf "$out/vgg_runs.tgz" $(ls -d *_eval *_eval_roi 2>/dev/null))
    ls -la "$out"
    ;;
status)
    for r in default keypoints pvgg; do echo "== $r"; tail -n 4 "$RUNS/$r/metrics.csv" 2>/dev/null || tail -c 600 "$RUNS/$r.log"; done
    nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv,noheader
    uptime
    if [ -n "${2:-}" ]; then exec bash "$0" collect "$2"; fi
    ;;
collect)
    out=${2:?collect OUTDIR}
    for r in default keypoints; do
        if [ -f "$RUNS/$r.pt" ]; then split -b 15M -d "$RUNS/$r.pt" "$out/$r.pt.part"; else echo "$r: not exported yet"; fi
    done
    tar -C "$RUNS" -czf "$out/logs_metrics_pvgg_eval.tgz" $(cd "$RUNS" && ls -d *.log */metrics.csv */history.json pvgg_eval 2>/dev/null)
    ls -la "$out"
    ;;
*)
    echo "usage: $0 start|setup|render|launch|status|collect OUTDIR | start-vgg OUTDIR SECONDS|launch-vgg|wait-vgg OUTDIR SECONDS|collect-vgg OUTDIR" >&2
    exit 2
    ;;
esac
