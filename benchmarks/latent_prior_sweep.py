"""Latent prior weight sweep (stop 12, reverted): DS1 latent fits of the held-out ten and the report five.

    python benchmarks/latent_prior_sweep.py PLAN W [W ...]
"""
import json, sys, tempfile, statistics
from pathlib import Path
sys.path.insert(0, "benchmarks")
import models as M
from neuralbrdf.data.nbrdf import REPORT_MATERIALS
from neuralbrdf.data.proxy_corpus import HELD_OUT
ref = json.load(open("runs/latent_sweep/models_latentshipped.json"))["nlb_vs_abc"]["materials"]
names = (*HELD_OUT, *REPORT_MATERIALS)
sources = [{"nbrdf": str(M.SHARED_DATA / "merl-nbrdf" / f"{n}.h5")} for n in names]
out = {}
plan = sys.argv[1]
for w in sys.argv[2:]:
    with tempfile.TemporaryDirectory() as tmp:
        m = M._latent_fit(Path(tmp), f"w{w}", sources, "--data.plan", plan, "--model.latent_prior_weight", w)
    rows = {n: m[f"fit/hemisphere_logcos_rmse/{n}"] for n in names}
    out[w] = rows
    for group, members in (("held_out", HELD_OUT), ("report", REPORT_MATERIALS)):
        v = [rows[n] for n in members]
        abc = [ref[n]["abc_DS1"] for n in members]; low = [ref[n]["abc_low2012"] for n in members]
        print(f"{plan} w={w} {group}: median {statistics.median(v):.4f} (x ABC {statistics.median(v)/statistics.median(abc):.2f}) "
              f"mean {statistics.mean(v):.4f} wins ABC {sum(a<b for a,b in zip(v,abc))}/{len(v)} Low {sum(a<b for a,b in zip(v,low))}/{len(v)} "
              f"fit {m['fit/wall_time_s']:.0f}s", flush=True)
Path(f"/tmp/prior_sweep_{plan}_{'_'.join(sys.argv[2:])}.json").write_text(json.dumps(out, indent=1))
