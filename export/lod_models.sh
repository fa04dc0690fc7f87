#!/usr/bin/env bash
# The models of export/scenes/lod_demo.xml and their cost ladders (docs/select.md), in one command:
# the README's main job (spectral MLP, configs/spectral_mlp.yaml, shipped DS1 data) for each of the
# four virtual materials, exported with its RGB head to out/lod/models/NAME.onnx, then
# `neuralbrdf ladder` for each (out/lod/models/NAME.ladder/, where `neuralbrdf select` finds it).
# Needs only the package (no ../shared data).  Steps already done (a run's checkpoint, a model file,
# a ladder) are kept, so an interrupted run continues where it stopped (a training run without its
# best checkpoint starts again); `rm -rf out/lod` starts afresh.
# About 3 min of training, 1 min of export and ~3 min of ladder per material on 2 idle cores.
#   bash export/lod_models.sh [PYTHON]      (from anywhere; default PYTHON: .venv/bin/python)
#   then: neuralbrdf select export/scenes/lod_demo.xml --out out/lod/SELECTED.xml
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${1:-.venv/bin/python}
for m in gold gonio cyan magenta; do
  run=out/lod/runs/$m model=out/lod/models/$m.onnx
  [ -f "$run/checkpoints/best.ckpt" ] || OMP_NUM_THREADS=1 "$PYTHON" train.py fit --config configs/spectral_mlp.yaml \
      --data.virtual "$m" --run_dir "$run" --overwrite --trainer.enable_progress_bar false
  [ -f "$model" ] || "$PYTHON" export/to_onnx.py --ckpt "$run/checkpoints/best.ckpt" --out "$model"
  [ -f "out/lod/models/$m.ladder/ladder.json" ] || OMP_NUM_THREADS=1 "$PYTHON" -m neuralbrdf ladder "$model"
done
echo "models and ladders of export/scenes/lod_demo.xml are in out/lod/models/"
