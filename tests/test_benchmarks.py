"""``benchmarks/run.py --quick`` runs end to end (train, export with fast paths, renders of every
kind in both variants and backends, image errors of the fast paths, throughput with the fused
kernel's own time) and writes the JSON its README documents; the kernel time excludes tracing."""

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

import onnx_fixtures as fx

ROOT = Path(__file__).resolve().parents[1]
RGB_CONFIGS = {
    "roughconductor/symbolic", "roughconductor/wavefront", "spectral_mlp/drjit", "spectral_mlp/onnxruntime",
    "spectral_mlp_integrated/drjit", "abc/drjit", "auto/drjit", "nlb/drjit", "nlb_fast/drjit", "flat_model/drjit",
    "nlb_spectral/drjit", "nlb_spectral/onnxruntime", "nlb_spectral_integrated/drjit",
}
SPECTRAL_CONFIGS = (RGB_CONFIGS - {"spectral_mlp_integrated/drjit", "nlb_spectral_integrated/drjit"}) | {
    "nlb_spectral_fast/drjit"}


@pytest.mark.slow
def test_quick_benchmark_writes_the_documented_results(tmp_path):
    out = tmp_path / "results.json"
    result = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "run.py"), "--quick", "--out", str(out)],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=1200,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert "x rc median" in result.stdout and "drjit_kernel" in result.stdout  # the printed table
    results = json.loads(out.read_text())
    assert {"machine", "settings", "seed", "models", "fast_paths", "render", "throughput", "targets", "peak_rss_mb",
            "load_average"} <= set(results)
    assert results["quick"] is True and len(results["load_average"]["before"]) == 3
    assert results["models"]["spectral_mlp"]["export_max_rel_error"] <= 1e-5
    assert set(results["fast_paths"]) == {"spectral_mlp f_rgb", "nlb f_fast", "nlb_spectral f_rgb", "nlb_spectral f_fast"}
    assert all(entry["image_delta_e2000_mean"] >= 0 for entry in results["fast_paths"].values())
    assert results["models"]["nlb_spectral"]["hidden_units"].count("/48") == 3
    assert results["models"]["auto"]["choice"] in ("abc", "nlb_spectral")
    assert set(results["render"]) == {"llvm_ad_rgb", "llvm_ad_spectral"}
    rgb, spectral = results["render"]["llvm_ad_rgb"], results["render"]["llvm_ad_spectral"]
    assert set(rgb["configs"]) == RGB_CONFIGS and set(spectral["configs"]) == SPECTRAL_CONFIGS
    for variant in (rgb, spectral):
        for name, config in variant["configs"].items():
            assert config["median_s"] > 0 and config["shortest_s"] <= config["median_s"] and len(config["times_s"]) >= 2
            if not name.startswith("roughconductor"):
                assert variant["ratios"][name]["median"] > 0 and variant["ratios"][name]["shortest"] > 0
    # which output each configuration evaluated
    assert rgb["configs"]["spectral_mlp/drjit"]["output"] == "f_rgb"
    assert rgb["configs"]["spectral_mlp/onnxruntime"]["output"] == "f_rgb"
    assert rgb["configs"]["spectral_mlp_integrated/drjit"]["output"] == "f"
    assert 1 <= len(rgb["configs"]["spectral_mlp_integrated/drjit"]["rgb_rule_wavelengths_nm"]) <= 31
    assert spectral["configs"]["spectral_mlp/drjit"]["output"] == "f"
    assert rgb["configs"]["nlb_fast/drjit"]["output"] == spectral["configs"]["nlb_fast/drjit"]["output"] == "f_fast"
    assert rgb["configs"]["nlb_spectral/drjit"]["output"] == rgb["configs"]["nlb_spectral/onnxruntime"]["output"] == "f_rgb"
    assert rgb["configs"]["nlb_spectral_integrated/drjit"]["output"] == spectral["configs"]["nlb_spectral/drjit"]["output"]
    assert spectral["configs"]["nlb_spectral/drjit"]["output"] == "f"
    assert spectral["configs"]["nlb_spectral_fast/drjit"]["output"] == "f_fast"
    assert set(rgb["image_errors"]) == {"spectral_mlp/drjit vs spectral_mlp_integrated/drjit", "nlb_fast/drjit vs nlb/drjit",
                                        "nlb_spectral/drjit vs nlb_spectral_integrated/drjit"}
    assert set(spectral["image_errors"]) == {"nlb_fast/drjit vs nlb/drjit", "nlb_spectral_fast/drjit vs nlb_spectral/drjit"}
    assert set(results["throughput"]) == {"spectral_mlp", "spectral_mlp rgb head", "nlb", "nlb fast path", "abc",
                                          "nlb_spectral", "nlb_spectral rgb head", "nlb_spectral fast path"}
    for name, model in results["throughput"].items():
        expected = {"onnxruntime", "drjit", "drjit_kernel"} | ({"pytorch"} if model["output"] == "f" else set())
        assert set(model["backends"]) == expected, name
        assert all(b["queries_per_s"] > 0 for b in model["backends"].values())


def test_the_kernel_time_excludes_tracing(tmp_path):
    from neuralbrdf.kinds import load_model
    from neuralbrdf.render.drjit_onnx import DrJitGraph
    from neuralbrdf.study.cost import drjit_evaluate, drjit_inputs, drjit_kernel_seconds, probe_inputs

    graph = DrJitGraph(load_model(fx.write_nlb_like(tmp_path / "nlb.onnx")).proto)
    inputs = drjit_inputs(probe_inputs(2**16, False), False)
    drjit_evaluate(graph, inputs)  # compiled once
    start = time.perf_counter()
    kernel = drjit_kernel_seconds(graph, inputs)
    wall = time.perf_counter() - start
    assert 0 < kernel < wall
