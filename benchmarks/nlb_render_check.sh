#!/usr/bin/env bash
# Rendered-image check of NLB latent fits : the held-out ten fitted from DS1 with each
# pretrained network, exported, and scored by `neuralbrdf evaluate` against the NBRDF proxy's own
# export (material-preview scene, llvm_ad_rgb, 128 px, 256 spp; direction metrics beside the image).
#   benchmarks/nlb_render_check.sh OUT_DIR [CHECKPOINT[:PRIOR_WEIGHT[:PRIOR_CODES]] ...]
# PRIOR_WEIGHT is the fit's model.latent_prior_weight (default 0, no prior), PRIOR_CODES its
# model.latent_prior_codes (default: the config's, all); the default list is nlb_compact
# nlb_latent32_scratch nlb_latent32_blends nlb_latent32_blends:0.01 (the default fit).
# Run from the repository root, with the package's environment active (../shared beside the checkout).
# Writes OUT_DIR/eval_<label>_<material>/{evaluation.json,comparison.png,...} (label: the checkpoint,
# with _prior<weight> where there is one) and OUT_DIR/summary.tsv (one row per label and material).  ~1 min per network's fit plus
# ~10 s per evaluation on 2 cores.
set -euo pipefail
out=${1:?usage: nlb_render_check.sh OUT_DIR [CHECKPOINT[:PRIOR_WEIGHT[:PRIOR_CODES]] ...]}; shift
[ $# -gt 0 ] && models=("$@") || models=(nlb_compact nlb_latent32_scratch nlb_latent32_blends nlb_latent32_blends:0.01)
merl=../shared/data/merl-nbrdf
materials=$(python -c "from neuralbrdf.data.proxy_corpus import HELD_OUT; print(' '.join(HELD_OUT))")
sources=$(python -c "import json; from neuralbrdf.data.proxy_corpus import HELD_OUT; \
print(json.dumps([{'nbrdf': '$merl/' + n + '.h5'} for n in HELD_OUT]))")
mkdir -p "$out"
for m in $materials; do
  [ -f "$out/truth_$m.onnx" ] || neuralbrdf export-truth "$merl/$m.h5" --out "$out/truth_$m.onnx" > /dev/null
done
labels=()
for spec in "${models[@]}"; do
  IFS=: read -r ck weight codes <<< "$spec"
  weight=${weight:-0}; codes=${codes:-all}
  # a number, and the label names it unless it is zero (0, 0.0, ...)
  python -c "import sys; w = float(sys.argv[1]); sys.exit(0 if w >= 0 else 1)" "$weight" 2>/dev/null \
    || { echo "nlb_render_check.sh: $spec: the prior weight must be a non-negative number" >&2; exit 2; }
  label=$(basename "$ck" .ckpt)
  python -c "import sys; sys.exit(float(sys.argv[1]) == 0)" "$weight" && label=${label}_prior$weight
  [[ $codes == all ]] || label=${label}_$codes
  labels+=("$label")
  python train.py fit --config configs/nlb_latent.yaml --data.sources "$sources" --data.plan DS1 \
    --model.checkpoint "$ck" --model.latent_prior_weight "$weight" --model.latent_prior_codes "$codes" \
    --run_dir "$out/fit_$label" \
    --trainer.enable_progress_bar false > "$out/fit_$label.log"
  for m in $materials; do
    neuralbrdf export --ckpt "$out/fit_$label/checkpoints/fitted.ckpt" --out "$out/${label}_$m.onnx" --material "$m" > /dev/null
    neuralbrdf evaluate "$out/${label}_$m.onnx" --truth "$out/truth_$m.onnx" --out-dir "$out/eval_${label}_$m" \
      --variant llvm_ad_rgb > "$out/eval_${label}_$m.log"
  done
done
python - "$out" "${labels[@]}" <<'PY'
import json, sys
from pathlib import Path
from neuralbrdf.data.proxy_corpus import HELD_OUT
out, labels = Path(sys.argv[1]), sys.argv[2:]
keys = ("hemisphere_logcos_rmse", "image_delta_e2000_mean", "image_delta_e2000_p95", "image_rel_mse")
lines = ["model\tmaterial\t" + "\t".join(keys)]
for label in labels:
    for m in HELD_OUT:
        e = json.loads((out / f"eval_{label}_{m}" / "evaluation.json").read_text())
        lines.append("\t".join([label, m, *(f"{e[k]:.4g}" for k in keys)]))
(out / "summary.tsv").write_text("\n".join(lines) + "\n")
print("\n".join(lines))
PY
