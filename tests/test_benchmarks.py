"""``benchmarks/run.py --quick`` runs end to end (train, export, renders in both variants and
backends, throughput in three backends) and writes the JSON its README documents."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RENDER_CONFIGS = {
    "roughconductor/symbolic",
    "roughconductor/wavefront",
    "drjit/symbolic",
    "onnxruntime/wavefront",
    "flat_model_drjit/symbolic",
    "relu_model_drjit/symbolic",
}
RATIOS = {
    "drjit_vs_roughconductor_symbolic",
    "flat_model_drjit_vs_roughconductor_symbolic",
    "relu_model_drjit_vs_roughconductor_symbolic",
    "onnxruntime_vs_roughconductor_wavefront",
    "onnxruntime_vs_roughconductor_symbolic",
}


@pytest.mark.slow
def test_quick_benchmark_writes_the_documented_results(tmp_path):
    out = tmp_path / "results.json"
    result = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "run.py"), "--quick", "--out", str(out)],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert "drjit_vs_roughconductor_symbolic" in result.stdout  # the printed table
    results = json.loads(out.read_text())
    assert {"machine", "settings", "seed", "model", "render", "throughput", "targets", "peak_rss_mb"} <= set(results)
    assert results["quick"] is True and results["machine"]["cores"] >= 1
    for key, activation in (("model", "tanh"), ("relu_model", "relu")):
        assert results[key]["activation"] == activation
        assert results[key]["export_max_rel_error"] <= 1e-5
    assert set(results["render"]) == {"llvm_ad_rgb", "llvm_ad_spectral"}
    for variant in results["render"].values():
        assert set(variant["configs"]) == RENDER_CONFIGS and set(variant["ratios"]) == RATIOS
        for config in variant["configs"].values():
            assert config["median_s"] > 0 and config["first_call_s"] > 0 and len(config["times_s"]) >= 2
        for ratio in variant["ratios"].values():
            assert ratio > 0
    for name in ("drjit/symbolic", "onnxruntime/wavefront", "relu_model_drjit/symbolic"):
        rule = results["render"]["llvm_ad_rgb"]["configs"][name]["rgb_rule"]
        assert 1 <= len(rule["wavelengths_nm"]) <= 31 and rule["rms_relative_error"] <= 1e-3
    assert "rgb_rule" not in results["render"]["llvm_ad_spectral"]["configs"]["drjit/symbolic"]
    assert set(results["throughput"]) == {"spectral_mlp", "spectral_mlp_relu", "nlb_compact", "abc"}
    for model in results["throughput"].values():
        assert set(model["backends"]) == {"pytorch", "onnxruntime", "drjit"}
        assert all(b["queries_per_s"] > 0 and b["first_call_s"] > 0 for b in model["backends"].values())
        assert model["fastest"] in model["backends"]
