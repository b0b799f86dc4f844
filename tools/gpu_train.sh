#!/usr/bin/env bash
# One training call on a lent GPU machine, resumable across calls; also the two steps around it.
#
#   bash tools/gpu_train.sh prepare          # here, once: wheels the device lacks -> .whl/
#   bash tools/gpu_train.sh                  # ON THE DEVICE (device run, carry [".whl", ".gpu"])
#   bash tools/gpu_train.sh collect FILES_AT # here, after each call: parts -> .gpu/NAME, export
#
# A device call (tools/README.md, "Training on a GPU machine"):
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
#   DEADLINE=epoch seconds (the call's end: MINUTES is fitted to it after the data and the bench,
#   less RESERVE_S=60); BENCH_MAX_S=240 (the bench's share: a pair still compiling is cut)
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
# the device returns at most 8 files of at most 16 MiB, 64 MiB in all, per call; what a call
# cannot return stays on the machine for `rest`. What travels there (tree + carry) is at most
# 64 MiB too: a run's state goes up in bundles of UP_MIB (`stage` here, `receive` there). 21 MiB
# cuts the full size's state (81.4 MiB: weights and Adam's two moments) into 4 bundles, as 24
# did, and leaves the tracked tree 41 MiB (tests/test_repository_size.py)
MAX_FILES=8; MAX_MIB=${PART_MIB:-16}; MAX_TOTAL_MIB=${MAX_TOTAL_MIB:-60}; UP_MIB=${UP_MIB:-21}
UP=.up/$NAME
bytes() { awk -v m="$1" 'BEGIN { printf "%d", m * 1048576 }'; }
SITE=
py() { PYTHONPATH="${SITE:+$SITE:}$REPO${PYTHONPATH:+:$PYTHONPATH}" \
         ${T_TIMEOUT:+timeout --signal=KILL "$T_TIMEOUT"} "$PY" "$@"; }
T() { py -m tpnet_ref.cli "$@"; }
# a run directory's parts checked against its checkpoint.json, by the loader's own check
parts_ok() {
    py -c "import sys
from tpnet_ref.training.checkpoint import checkpoint_bytes
try:
    checkpoint_bytes(sys.argv[1])
except (OSError, ValueError) as e:
    sys.exit(f'gpu_train: {e}')" "$1"
}
# DEADLINE (epoch seconds, empty: none): the call's end; MINUTES is then what is left after the
# data and the bench, less RESERVE_S for the last checkpoint and the copy (a device call that
# outlasts its limit brings nothing back)
DEADLINE=${DEADLINE:-}; RESERVE_S=${RESERVE_S:-60}; BENCH_MAX_S=${BENCH_MAX_S:-240}
fit_minutes() {
    [ -n "$DEADLINE" ] || return 0
    MINUTES=$(awk -v l=$(( DEADLINE - $(date +%s) - RESERVE_S )) 'BEGIN { printf "%.2f", (l > 30 ? l : 30) / 60 }')
    echo "gpu_train: $MINUTES minutes of training left before DEADLINE"
}

# copy files (in the order given) into $OUT/$NAME while the call's total stays within
# MAX_TOTAL_MIB; the names left over go to $RUN.rest for the next call (`rest`)
send() {
    local total=0 limit f sz; limit=$(bytes "$MAX_TOTAL_MIB")
    mkdir -p "$OUT/$NAME"; : > "$RUN.rest"
    for f in "$@"; do
        sz=$(stat -c %s "$f")
        if [ $((total + sz)) -le "$limit" ]; then cp "$f" "$OUT/$NAME/"; total=$((total + sz))
        else basename "$f" >> "$RUN.rest"; fi
    done
    if [ -s "$RUN.rest" ]; then
        echo "gpu_train: $(wc -l < "$RUN.rest") files stay on the machine (at most $MAX_TOTAL_MIB MiB come back a call): next, at once, a call of \`bash tools/gpu_train.sh rest\` (carry [\".whl\"] only)"
    else
        rm -f "$RUN.rest"
    fi
}
# the run's state, brought up in bundles by earlier calls (`stage` here): once every bundle is
# on the machine, it becomes $RUN (parts cut as the run wrote them, checked against the SHA-256
# in checkpoint.json); returns 1 while bundles are missing
assemble() {
    local man=$UP/1/manifest k i
    [ -f "$man" ] || return 0
    k=$(awk '$1 == "bundles" {print $2}' "$man")
    for i in $(seq 1 "$k"); do
        [ -f "$UP/$i/chunk" ] || { echo "gpu_train: bundle $i of $k not on the machine yet ($UP/$i)"; return 1; }
    done
    rm -rf "$RUN.in"; mkdir -p "$RUN.in"
    cp "$UP/1/checkpoint.json" "$UP/1/log.jsonl" "$RUN.in/"
    for i in $(seq 1 "$k"); do cat "$UP/$i/chunk"; done \
        | split -b "$(awk '$1 == "part_bytes" {print $2}' "$man")" -d -a 3 - "$RUN.in/checkpoint.pt."
    parts_ok "$RUN.in" || { echo "gpu_train: the bundles in $UP do not rebuild the run: incomplete or mixed stages" >&2; return 1; }
    rm -rf "$RUN"; mv "$RUN.in" "$RUN"; rm -rf "$UP"
    echo "gpu_train: $RUN assembled from $k bundles"
}

case "${1:-device}" in
stage)     # here: the run's state -> bundles of UP_MIB for a fresh machine (one call each)
    [ -f "$RUN/checkpoint.json" ] || { echo "no $RUN/checkpoint.json to stage" >&2; exit 1; }
    mapfile -t parts < <("$PY" -c "import json,sys; print('\n'.join(json.load(open(sys.argv[1]))['checkpoint_files']['files']))" "$RUN/checkpoint.json")
    part_bytes=$(stat -c %s "$RUN/${parts[0]}")
    rm -rf "$UP"; mkdir -p "$UP/tmp"
    for f in "${parts[@]}"; do cat "$RUN/$f"; done | split -b "$(bytes "$UP_MIB")" -d -a 2 - "$UP/tmp/c"
    i=0
    for c in "$UP"/tmp/c*; do i=$((i + 1)); mkdir -p "$UP/$i"; mv "$c" "$UP/$i/chunk"; done
    rmdir "$UP/tmp"
    cp "$RUN/checkpoint.json" "$RUN/log.jsonl" "$UP/1/"
    printf 'bundles %s\npart_bytes %s\n' "$i" "$part_bytes" > "$UP/1/manifest"
    tree=$(cd "$REPO" && git ls-files -co --exclude-standard -z | du --files0-from=- -cb | tail -1 | cut -f1)
    whl=$( (du -sb .whl 2>/dev/null || true) | cut -f1); whl=${whl:-0}
    echo "gpu_train: $RUN staged in $i bundles of at most $UP_MIB MiB; the tree $((tree >> 20)) MiB + .whl $((whl >> 20)) MiB travel with each (64 MiB a call)"
    for j in $(seq 1 "$i"); do
        if [ "$j" -lt "$i" ]; then cmd="bash tools/gpu_train.sh receive"; else cmd="<the training command>"; fi
        echo "  device call $j: carry [\".whl\", \"$UP/$j\"]  command: $cmd"
    done
    exit 0 ;;

prepare)   # here: the wheels the device image lacks (it has torch, numba, h5py, scipy, tqdm)
    mkdir -p .whl
    "$PY" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
        --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 \
        --platform manylinux2014_x86_64 -d .whl pymunk==7.3.1 cffi==2.0.0 pycparser==2.23
    ls -l .whl
    du -sh .whl .gpu 2>/dev/null || true
    exit 0 ;;
collect)   # here: the files calls returned (a call and its `rest` calls) -> .gpu/NAME, then
           # the native weights file; .gpu/NAME is replaced only by a complete, checked state
    shift; [ $# -ge 1 ] || { echo "usage: tools/gpu_train.sh collect FILES_AT [FILES_AT ...]" >&2; exit 2; }
    rm -rf "$RUN.in"; mkdir -p "$RUN.in"
    for src in "$@"; do
        [ -d "$src/$NAME" ] || { echo "no $src/$NAME" >&2; exit 1; }
        cp "$src/$NAME"/* "$RUN.in"/
    done
    [ -f "$RUN.in/checkpoint.json" ] || { echo "no checkpoint.json in $*" >&2; exit 1; }
    parts_ok "$RUN.in" || { echo "gpu_train: parts did not come back or come from other calls: a \`rest\` call brings the missing ones (then collect every folder)" >&2; exit 1; }
    rm -rf "$RUN"; mv "$RUN.in" "$RUN"
    mkdir -p runs
    T train export "$RUN" "runs/gpu-$NAME.h5"
    echo "next: tpnet train score $DATA <current weights> runs/gpu-$NAME.h5 (validation only)"
    exit 0 ;;
receive)   # on the device: keep the bundle this call carried; assemble once all are there
    assemble || true
    exit 0 ;;
rest)      # on the device, right after a call: the files it could not return
    [ -s "$RUN.rest" ] || { echo "gpu_train: nothing left to return ($RUN.rest)" >&2; exit 1; }
    OUT=${OUT:-out}; rm -rf "${OUT:?}/$NAME"
    mapfile -t left < "$RUN.rest"
    send "${left[@]/#/$RUN/}"
    ls -l "$OUT/$NAME"
    exit 0 ;;
device) ;;
*) echo "usage: tools/gpu_train.sh [prepare | stage | collect FILES_AT... | receive | rest]" >&2; exit 2 ;;
esac
assemble || { echo "gpu_train: bundles missing: no training on a partial state" >&2; exit 3; }

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
    bench_end=$(( $(date +%s) + BENCH_MAX_S ))
    for c in $BENCH_COMPILE; do
        for b in $BENCH_BATCHES; do
            left=$(( bench_end - $(date +%s) ))
            if [ "$left" -le 5 ]; then
                echo "gpu_train: bench batch $b compile $c: skipped (BENCH_MAX_S=$BENCH_MAX_S spent)"
                continue
            fi
            # a pair that outlasts what is left of the bench's time is cut and scores 0
            out=$(T_TIMEOUT=$left T train bench --size "$SIZE" --batch "$b" --rollouts 8 --iters 10 \
                --device "$DEVICE" --threads "$THREADS" --compile "$c" --precisions float32 \
                --shape-weight "$SHAPE" --match-weight "$MATCH") || out="(cut or failed: rc $?)"
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
train() {
fit_minutes
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
}
# a compiled step that fails in the run (not in the bench) falls back to eager, resuming what
# the failed run checkpointed, rather than losing the lease
if ! train; then
    [ "$COMPILE" != off ] || exit 1
    echo "gpu_train: the run failed with --compile $COMPILE; again eager" >&2
    COMPILE=off; train
fi

# --- 4. what comes back ----------------------------------------------------------------------
rm -f "$OUT/$NAME"/*
send "$RUN"/checkpoint.json "$RUN"/log.jsonl "$RUN"/checkpoint.pt*
n=$(find "$OUT" -type f | wc -l)
big=$(find "$OUT" -type f -size +"$(bytes "$MAX_MIB")"c)
if [ "$n" -gt "$MAX_FILES" ] || [ -n "$big" ]; then
    echo "gpu_train: $n files under $OUT (at most $MAX_FILES come back), over ${MAX_MIB} MiB: ${big:-none}" >&2
    exit 1
fi
"$PY" -c "import json,sys; s=json.load(open(sys.argv[1])); print(f\"gpu_train: {sys.argv[1]} step {s['step']}/{s['total_steps']}, {s['windows_seen']} windows, {s['wall_s']:.0f} s, {s['stopped']}, budget {s.get('budget')}, last validation {s.get('last_val')}\")" "$RUN/checkpoint.json"
ls -l "$OUT/$NAME"
