#!/usr/bin/env bash
# Refresh every generated result and figure of the docs after the shipped weights change
# (e.g. a new weights/tpnet-m4.h5). Its tpnet eval step took 122 s on 2 CPU cores (the first line
# of docs/results.md records each run's time and machine); the animation and the camera figure
# come on top.
#
#   bash tools/refresh_docs.sh
#
# 1. weights/tpnet-m3.h5 and tpnet-m5.h5 back from git history (not tracked: weights/README.md)
# 2. tpnet eval on the 60 held-out cases -> docs/results.md (every cell with its spread),
#    docs/eval_*.png (including eval_spread.png), docs/eval_curves.csv, docs/eval_cases.csv
# 3. the m = 4 headline table copied from docs/results.md into README.md and weights/MODEL_CARD.md
# 4. docs/rollout.gif (tpnet animate) and docs/observe_example.png (the camera path)
# The "Network sizes" section of docs/results.md is kept as it is; it needs the training grid
# (bench/sizes.py --data data/grid-m4.h5, docs/results.md names the command).
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/restore_weights.sh
tpnet eval --weights weights/tpnet-m3.h5 --weights weights/tpnet-m4.h5 \
    --weights weights/tpnet-m5.h5 --generalisation --out docs --quiet
python tools/headline_tables.py
tpnet animate -o docs/rollout.gif
python bench/probes/observe_figure.py -o docs/observe_example.png
git status --short -- README.md weights/MODEL_CARD.md docs
