#!/usr/bin/env bash
# One training call on a lent GPU machine, resumable across calls; also the two steps around it.
#
#   bash tools/gpu_train.sh prepare          # here, once: wheels the device lacks -> .whl/
#   bash tools/gpu_train.sh                  # ON THE DEVICE (device run, carry [".whl", ".gpu"])
#   bash tools/gpu_train.sh collect FILES_AT # here, after each call: parts -> .gpu/NAME, export
#
# A device call (docs/training.md, "Running on a GPU session"):
#   1. installs what the machine lacks (pymunk: from the wheels carried in .whl/, else pip);
#   2. generates the training data on all its cores unless the (warm) machine still has it;
#   3. trains: a new run from $INIT, or --resume of the run in .gpu/$NAME (the parts brought
#      back by the last call and put there by `collect`; on a warm machine the same files),
#      eager by default (COMPILE=auto: the step captured by torch.compile(mode="reduce-overhead"),
#      CUDA graphs, not yet run on a GPU); the schedule is fitted to $BUDGET minutes of training
#      in all, each call stops after $MINUTES with a checkpoint in parts of 16 MiB;
#   4. copies checkpoint.json, the parts and log.jsonl to $OUT/$NAME (the device returns at most
#      8 files of 16 MiB: checked here, the call fails loudly if they would not come back).
#
# Settings (environment; defaults: the full m = 4 network fine-tuned from the shipped file):
#   M=4 SIZE=full NAME=m$M INIT=weights/tpnet-m4.h5 (empty: from scratch at $SIZE)
#   BUDGET=6.5 MINUTES=6.5 (one call: a session has 15 minutes of device time, its start
#   included) BATCH=512 LR=1e-4 (3e-4 undid more of the shipped model than its schedule won
#   back: docs/training.md) SHAPE=4 MATCH=0 NOISE=0.001 RECIPE=paper
#   COMPILE=off DEVICE=auto THREADS=8 WORKERS=$(nproc) BENCH=0 (1: `tpnet train bench` first;
#   a new run times its own step anyway: budget.bench_windows_per_s in checkpoint.json)
#   DATA=data/grid-m$M.h5 DATA_ARGS= (extra `tpnet data generate` options; CI: a tiny grid)
#   TRAIN_ARGS= (extra `tpnet train run` options for a new run) OPTIM=none (Adam state kept in
#   the checkpoint: none = model only, 2 parts for the full network; full = 6 parts)
#   PY=python3  OUT=$OUT (the device's folder of files to return; default out/ here)
#   WORK=the repository (where data/, .whl/, .gpu/, runs/ are; CI points it at a scratch folder)
#   STOP_STEP= (stop this call at that global step; CI stops the first call half-way)
#   BUDGET= (empty: no --budget-minutes; give --epochs in TRAIN_ARGS)
#   PRESET=released: a new run from scratch with `tpnet train run --preset released` (Keras
#   initialisation, the released windows: DATA defaults to data/grid-m$M-released.h5, made
#   with --windows released; Adam at a constant $LR, no warm-up, no clipping, the published
#   loss) at batch $BATCH; INIT, SHAPE, MATCH, NOISE and BUDGET are not used (the schedule is
#   constant: the run goes on call after call); use OPTIM=full so Adam's state travels
#   (LR defaults to the released 1e-3 there)
#   BENCH_BATCHES="512 1024 2048" BENCH_COMPILE="off reduce-overhead": with BENCH=1, the
#   windows/s of every pair first (the first minute of a lease); BATCH_AUTO=1 then trains a
#   new run with the fastest pair
set -euo pipefail
REPO=$(cd "$(dirname "$0")/.." && pwd)
cd "${WORK:-$REPO}"

M=${M:-4}; SIZE=${SIZE:-full}; NAME=${NAME:-m$M}; INIT=${INIT-$REPO/weights/tpnet-m4.h5}
PRESET=${PRESET:-}
BUDGET=${BUDGET-6.5}; MINUTES=${MINUTES:-6.5}; BATCH=${BATCH:-512}
if [ "$PRESET" = released ]; then LR=${LR:-1e-3}; else LR=${LR:-1e-4}; fi
SHAPE=${SHAPE:-4}; MATCH=${MATCH:-0}; NOISE=${NOISE:-0.001}; RECIPE=${RECIPE:-paper}
COMPILE=${COMPILE:-off}; DEVICE=${DEVICE:-auto}; THREADS=${THREADS:-8}
WORKERS=${WORKERS:-$(nproc)}; BENCH=${BENCH:-0}; STOP_STEP=${STOP_STEP:-}; DATA=${DATA:-data/grid-m$M.h5}
DATA_ARGS=${DATA_ARGS:-}; TRAIN_ARGS=${TRAIN_ARGS:-}; OPTIM=${OPTIM:-none}; PY=${PY:-python3}
BENCH_BATCHES=${BENCH_BATCHES:-$BATCH}; BENCH_COMPILE=${BENCH_COMPILE:-$COMPILE}
BATCH_AUTO=${BATCH_AUTO:-0}
if [ "$PRESET" = released ]; then
    DATA=${DATA_RELEASED:-data/grid-m$M-released.h5}; DATA_ARGS="--windows released $DATA_ARGS"
elif [ -n "$PRESET" ]; then
    echo "gpu_train: PRESET must be empty or 'released', got '$PRESET'" >&2; exit 2
fi
RUN=.gpu/$NAME
MAX_FILES=8; MAX_MIB=16
SITE=
T() { PYTHONPATH="${SITE:+$SITE:}$REPO${PYTHONPATH:+:$PYTHONPATH}" "$PY" -m tpnet_ref.cli "$@"; }

case "${1:-device}" in
prepare)   # here: the wheels the device image lacks (it has torch, numba, h5py, scipy, tqdm)
    mkdir -p .whl
    "$PY" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
        --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 \
        --platform manylinux2014_x86_64 -d .whl pymunk==7.3.1 cffi==2.0.0 pycparser==2.23
    ls -l .whl
    du -sh .whl .gpu 2>/dev/null || true
    exit 0 ;;
collect)   # here: the files a call returned -> .gpu/NAME, then the native weights file
    src=${2:?usage: tools/gpu_train.sh collect FILES_AT}
    [ -f "$src/$NAME/checkpoint.json" ] || { echo "no $src/$NAME/checkpoint.json" >&2; exit 1; }
    mkdir -p "$RUN"
    rm -f "$RUN"/checkpoint.pt "$RUN"/checkpoint.pt.[0-9]*
    cp "$src/$NAME"/* "$RUN"/
    mkdir -p runs
    T train export "$RUN" "runs/gpu-$NAME.h5"
    echo "next: tpnet train score $DATA <current weights> runs/gpu-$NAME.h5 (validation only)"
    exit 0 ;;
device) ;;
*) echo "usage: tools/gpu_train.sh [prepare | collect FILES_AT]" >&2; exit 2 ;;
esac

# --- 1. what the machine lacks -------------------------------------------------------------
if ! "$PY" -c "import pymunk" 2>/dev/null; then
    SITE=/tmp/site
    if ls .whl/*.whl >/dev/null 2>&1; then
        "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
            --target "$SITE" .whl/*.whl
    else
        "$PY" -m pip install -q --target "$SITE" pymunk
    fi
fi
OUT=${OUT:-out}
mkdir -p "$OUT/$NAME"

# --- 2. data ---------------------------------------------------------------------------------
if [ ! -f "$DATA" ]; then
    mkdir -p "$(dirname "$DATA")"
    # shellcheck disable=SC2086
    T data generate -o "$DATA.part" --m "$M" --workers "$WORKERS" --no-test --quiet $DATA_ARGS
    mv "$DATA.part" "$DATA"
fi

# --- 3. train --------------------------------------------------------------------------------
if [ "$BENCH" = 1 ]; then
    best=0; best_b=$BATCH; best_c=$COMPILE
    for c in $BENCH_COMPILE; do
        for b in $BENCH_BATCHES; do
            out=$(T train bench --size "$SIZE" --batch "$b" --rollouts 8 --iters 10 \
                --device "$DEVICE" --threads "$THREADS" --compile "$c" --precisions float32 \
                --shape-weight "$SHAPE" --match-weight "$MATCH")
            echo "$out"
            wps=$(echo "$out" | awk '/8-step loss, float32/ {print $4}')
            echo "gpu_train: bench batch $b compile $c: $wps windows/s"
            if awk -v a="$wps" -v b="$best" 'BEGIN { exit !(a > b) }'; then
                best=$wps; best_b=$b; best_c=$c
            fi
        done
    done
    echo "gpu_train: fastest batch $best_b compile $best_c ($best windows/s)"
    if [ "$BATCH_AUTO" = 1 ]; then BATCH=$best_b; COMPILE=$best_c; fi
fi
common=(--device "$DEVICE" --threads "$THREADS" --compile "$COMPILE" --max-minutes "$MINUTES"
        --checkpoint-part-mib "$MAX_MIB" --checkpoint-optimizer "$OPTIM" --quiet)
[ -n "$STOP_STEP" ] && common+=(--max-steps "$STOP_STEP")
budget=(); [ -n "$BUDGET" ] && budget=(--budget-minutes "$BUDGET")
if [ -f "$RUN/checkpoint.json" ]; then
    T train run "$DATA" -o "$RUN" --resume "${common[@]}"
elif [ "$PRESET" = released ]; then
    # shellcheck disable=SC2086
    T train run "$DATA" -o "$RUN" --preset released --size "$SIZE" --batch "$BATCH" --lr "$LR" \
        --val-windows 2048 "${common[@]}" $TRAIN_ARGS
else
    init=(--size "$SIZE"); [ -n "$INIT" ] && init=(--init-from "$INIT")
    # shellcheck disable=SC2086
    T train run "$DATA" -o "$RUN" "${init[@]}" --recipe "$RECIPE" --batch "$BATCH" --lr "$LR" \
        --lr-min 1e-6 --warmup-steps 100 --shape-weight "$SHAPE" --match-weight "$MATCH" \
        --noise "$NOISE" --val-windows 2048 "${budget[@]}" "${common[@]}" $TRAIN_ARGS
fi

# --- 4. what comes back ----------------------------------------------------------------------
rm -f "$OUT/$NAME"/*
cp "$RUN"/checkpoint.json "$RUN"/log.jsonl "$OUT/$NAME"/
cp "$RUN"/checkpoint.pt* "$OUT/$NAME"/
n=$(find "$OUT" -type f | wc -l)
big=$(find "$OUT" -type f -size +$((MAX_MIB * 1024))k)
if [ "$n" -gt "$MAX_FILES" ] || [ -n "$big" ]; then
    echo "gpu_train: $n files under $OUT (at most $MAX_FILES come back), over ${MAX_MIB} MiB: ${big:-none}" >&2
    exit 1
fi
"$PY" -c "import json,sys; s=json.load(open(sys.argv[1])); print(f\"gpu_train: {sys.argv[1]} step {s['step']}/{s['total_steps']}, {s['windows_seen']} windows, {s['wall_s']:.0f} s, {s['stopped']}, budget {s.get('budget')}, last validation {s.get('last_val')}\")" "$RUN/checkpoint.json"
ls -l "$OUT/$NAME"
