#!/usr/bin/env bash
# The models of export/scenes/lod_demo.xml and their cost ladders (SPEC §11):
# the README's main job (spectral MLP, configs/spectral_mlp.yaml, shipped DS1 data) for each of the
# four virtual materials, exported to out/lod/models/NAME.onnx, then `neuralbrdf ladder` for each
# (out/lod/models/NAME.ladder/, where `neuralbrdf select` finds it).
# About 3 min of training and ~3 min of ladder per material (12 000 distillation steps per student) on 2 cores.
#   bash export/lod_models.sh [PYTHON]      (default: .venv/bin/python)
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${1:-.venv/bin/python}
for m in gold gonio cyan magenta; do
  OMP_NUM_THREADS=1 "$PYTHON" train.py fit --config configs/spectral_mlp.yaml --data.virtual "$m" \
      --run_dir "out/lod/runs/$m" --trainer.enable_progress_bar false
  "$PYTHON" export/to_onnx.py --ckpt "out/lod/runs/$m/checkpoints/best.ckpt" --out "out/lod/models/$m.onnx"
  OMP_NUM_THREADS=1 "$PYTHON" -m neuralbrdf ladder "out/lod/models/$m.onnx"
done
