#!/usr/bin/env bash
# The README's main job, rerun to remake the README's picture and its caption:
#   bash benchmarks/main_job.sh
# runs the main job's command from README.md (after its install step, with the neuralbrdf of
# NEURALBRDF, default .venv/bin/neuralbrdf) in out/main_job, then commits what the README shows:
# out/main_job/gold_eval/evaluation.json -> benchmarks/main_job/evaluation.json and
# comparison.png -> docs/gold_truth_vs_model.png, and rewrites the caption (docs/make_results.py).
# About a minute on 2 cores.
set -euo pipefail
cd "$(dirname "$0")/.."
NEURALBRDF=${NEURALBRDF:-.venv/bin/neuralbrdf}
python=$(dirname "$NEURALBRDF")/python

job=$(grep -m1 -F 'neuralbrdf demo --out-dir out/demo' README.md)
job=${job#*install -c constraints.txt . && }                 # the install is done
job=${job//.venv\/bin\/neuralbrdf/$NEURALBRDF}
job=${job//out\/demo/out\/main_job}
[[ $job == "$NEURALBRDF demo "* ]] || { echo "main_job.sh: README.md's main job not found" >&2; exit 1; }

rm -rf out/main_job
echo "main_job.sh: $job"
bash -c "$job"
mkdir -p benchmarks/main_job
cp out/main_job/gold_eval/evaluation.json benchmarks/main_job/evaluation.json
cp out/main_job/gold_eval/comparison.png docs/gold_truth_vs_model.png
"$python" docs/make_results.py
