"""``benchmarks/spectral_nlb.py`` (the accuracy benchmark and settings sweeps): a sweep of some methods
alone (``--methods``) summarises without the spectral NLB's comparisons, and bad options are refused."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import spectral_nlb  # noqa: E402


def rows(methods):
    values = {"a": 0.01, "b": 0.02, "c": 0.04}
    return {name: {m: {"hemisphere_logcos_rmse": v * (1 + i)} for i, m in enumerate(methods)} for name, v in values.items()}


def test_summary_of_the_spectral_mlp_alone_has_its_medians_and_no_comparisons():
    summary = spectral_nlb.summarise(rows(["spectral_mlp"]))
    metric = summary["hemisphere_logcos_rmse"]
    assert metric["median"] == {"spectral_mlp": pytest.approx(0.02)}
    assert metric["nlb_spectral_beats"] == {} and metric["median_nlb_spectral_over"] == {}
    assert summary["failed"] == {"spectral_mlp": 0}


def test_summary_with_the_spectral_nlb_compares_it_to_every_other_method():
    summary = spectral_nlb.summarise(rows(["nlb_spectral", "abc", "nlb"]))["hemisphere_logcos_rmse"]
    assert summary["nlb_spectral_beats"] == {"abc": 1.0, "nlb": 1.0}
    assert summary["median_nlb_spectral_over"] == {"abc": pytest.approx(0.5), "nlb": pytest.approx(1 / 3)}


@pytest.mark.parametrize("argv, message", [
    (["--methods", "spectral_mlp,ggx"], "unknown methods ['ggx']"),
    (["--groups", "nowhere"], "unknown groups ['nowhere']"),
])
def test_unknown_methods_and_groups_are_refused(tmp_path, argv, message):
    result = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "spectral_nlb.py"), *argv,
                             "--work", str(tmp_path / "work"), "--out", str(tmp_path / "out.json")],
                            capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert result.returncode == 2 and message in result.stderr, result.stderr
    assert not (tmp_path / "out.json").exists() and not (tmp_path / "work").exists()
