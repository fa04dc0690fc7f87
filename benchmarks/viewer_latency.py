"""How fast ``neuralbrdf view`` redraws after a slider move: the server's time per view and the time
from the mouse moving a slider to the redrawn view painted in headless Chromium.

    python benchmarks/viewer_latency.py [--work-dir out/viewer_latency] [--moves 6]

Files (made in ``--work-dir`` unless there, with the project's commands, a few minutes): the truth of
the virtual gold (``export-truth``), and ABC, the report's 3 × 10 spectral MLP and the spectral NLB
fitted to its shipped DS1 measurement; the viewer shows all four with that measurement.

1. **server**: every view computed for ``--moves`` new positions of the slider that drives it (no
   cache hit), in the quantity "f at λ" and in "luminance Y" (a spectral model's colour: a few
   wavelengths per pair through its sRGB rule); median wall and CPU time (the process's, onnxruntime's
   threads included) per view.
2. **page**: the CLI server and the page in headless Chromium (1400 × 1000 px, software WebGL), each
   view scrolled to the top of the window and its slider dragged with the mouse to ``--moves`` new
   positions, one step each, waiting for the redraw in between; from the page's own records
   (``window.viewerTimings``): the time from the input event to the redrawn view painted, the
   server's part, and the drawing of each view redrawn (views partly on screen are redrawn too); and
   the CPU time per update of the browser's processes and of the server's (from /proc), which the
   load of other processes does not inflate.

Writes ``benchmarks/viewer_latency.json`` (``--out``) with the load average before and after: the
machine is shared, so compare the views with one another in one run, and read absolute times with
the load beside them.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # the tests' DevTools-protocol browser

from browser import CHROMIUM, Browser  # noqa: E402

#: The slider that drives each view, and the positions it is dragged to.
DRIVERS = {
    "inplane": ("theta_i", [15, 25, 35, 45, 55, 65, 75, 5]),
    "spectrum": ("pick_theta", [20, 35, 50, 65, 80, 10, 45, 60]),
    "hemisphere": ("theta_i", [20, 30, 40, 50, 60, 70, 10, 80]),
    "lobe": ("theta_i", [25, 35, 45, 55, 65, 15, 5, 75]),
    "halfdiff": ("phi_d", [30, 45, 60, 75, 105, 120, 135, 150]),
    "sphere": ("light_theta", [15, 25, 35, 55, 65, 75, 5, 85]),
}
NEUTRAL = {"theta_i": 40, "pick_theta": 40, "phi_d": 90, "light_theta": 45}


def command(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "neuralbrdf", *args], check=True, cwd=ROOT, stdout=subprocess.DEVNULL)


def make_files(folder: Path) -> dict[str, Path]:
    """The truth and the three fits of the virtual gold (module docstring), made where missing."""
    folder.mkdir(parents=True, exist_ok=True)
    files = {name: folder / f"gold_{name}.onnx" for name in ("truth", "abc", "spectral_mlp", "nlb_spectral")}
    if not files["truth"].is_file():
        command("export-truth", "virtual:gold", "--out", str(files["truth"]))
    fits = {"abc": ["--config", "abc", "--data.virtual", "gold"],
            "spectral_mlp": ["--config", "spectral_mlp"],
            "nlb_spectral": ["--config", "nlb_spectral", "--data.sources", '[{"virtual": "gold"}]']}
    for name, config in fits.items():
        if files[name].is_file():
            continue
        run = folder / f"run_{name}"
        command("train", "fit", *config, "--data.eval_plan", "null", "--run_dir", str(run), "--overwrite",
                "--trainer.enable_progress_bar", "false")
        checkpoint = next(p for p in (run / "checkpoints" / "best.ckpt", run / "checkpoints" / "fitted.ckpt") if p.is_file())
        command("export", "--ckpt", str(checkpoint), "--out", str(files[name]), "--material", "gold")
    return files


def server_times(files: dict[str, Path], moves: int) -> dict:
    import neuralbrdf as nb
    from neuralbrdf.explorer.launch import open_scene

    models = [files[name] for name in ("abc", "spectral_mlp", "nlb_spectral")]
    scene = open_scene(models, files["truth"], nb.read("virtual:gold").samples, "virtual:gold")
    results = {}
    for channel in ("wavelength", "Y"):
        scene.forget()  # views that do not depend on the quantity are computed again too
        for view, (control, values) in DRIVERS.items():
            walls, cpus = [], []
            for value in values[:moves]:
                state = scene.defaults.updated({"channel": channel, control: str(value)})
                wall, cpu = time.perf_counter(), time.process_time()
                scene.view(view, state)
                walls.append(1e3 * (time.perf_counter() - wall))
                cpus.append(1e3 * (time.process_time() - cpu))
            results[f"{view}/{channel}"] = {"median_ms": statistics.median(walls), "median_cpu_ms": statistics.median(cpus),
                                            "ms": [round(t, 2) for t in walls]}
    return {"views": results, "rgb_rules": {s.label: s.rule.describe() for s in scene.sources if s.rule}}


def cpu_ms(root: int) -> float:
    """CPU time (user + system, ms) of process ``root`` and all its descendants, from /proc."""
    parents, times = {}, {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:  # the process ended meanwhile
            continue
        pid = int(stat.parent.name)
        parents[pid] = int(fields[1])
        times[pid] = int(fields[11]) + int(fields[12])
    family, grown = {root}, True
    while grown:
        more = {pid for pid, parent in parents.items() if parent in family} - family
        family |= more
        grown = bool(more)
    return 1e3 * sum(times.get(pid, 0) for pid in family) / os.sysconf("SC_CLK_TCK")


def page_times(files: dict[str, Path], moves: int) -> dict:
    args = [str(files[name]) for name in ("abc", "spectral_mlp", "nlb_spectral")]
    server = subprocess.Popen([sys.executable, "-m", "neuralbrdf", "view", *args, "--truth", str(files["truth"]),
                               "--table", "virtual:gold", "--port", "0"], stdout=subprocess.PIPE, text=True, cwd=ROOT)
    url = server.stdout.readline().split()[-1]
    results = {}
    try:
        with tempfile.TemporaryDirectory() as profile, Browser(Path(profile)) as browser:
            browser.open(url)
            browser.wait_for("document.body?.dataset.ready === '1'", timeout=300)
            settled = ("document.body.dataset.busy === '0' && "
                       "!document.body.dataset.stale.split(',').some((v) => v && document.getElementById('view-' + v)"
                       ".getBoundingClientRect().top < innerHeight && document.getElementById('view-' + v)"
                       ".getBoundingClientRect().bottom > 0)")
            start = time.perf_counter()
            for view, (control, values) in DRIVERS.items():
                browser.evaluate(f"document.getElementById('view-{view}').scrollIntoView({{block: 'start'}})")
                time.sleep(0.3)
                browser.wait_for(settled, timeout=120)
                browser.drag_slider(f"#control-{control}", NEUTRAL[control], steps=1)
                browser.wait_for(settled, timeout=120)
                first = browser.evaluate("window.viewerTimings.length")
                cpu_browser, cpu_server = cpu_ms(browser.process.pid), cpu_ms(server.pid)
                for value in values[:moves]:
                    browser.drag_slider(f"#control-{control}", value, steps=1)
                    time.sleep(0.05)
                    browser.wait_for(settled, timeout=120)
                cpu_browser, cpu_server = cpu_ms(browser.process.pid) - cpu_browser, cpu_ms(server.pid) - cpu_server
                timings = [t for t in browser.evaluate("window.viewerTimings")[first:] if t["cause"] == control]
                drawn = [t["draw_by_view_ms"].get(view) for t in timings if view in t["draw_by_view_ms"]]
                results[view] = {
                    "control": control,
                    "updates": len(timings),
                    "median_total_ms": statistics.median(t["total_ms"] for t in timings),
                    "median_server_ms": statistics.median(t["server_ms"] for t in timings),
                    "median_draw_ms": statistics.median(drawn) if drawn else None,
                    "views_redrawn": sorted({v for t in timings for v in t["draw_by_view_ms"]}),
                    # CPU per update, load-independent: the browser's processes (polling included) and the server's
                    "browser_cpu_ms_per_update": cpu_browser / max(len(timings), 1),
                    "server_cpu_ms_per_update": cpu_server / max(len(timings), 1),
                    "total_ms": [round(t["total_ms"], 1) for t in timings],
                }
            results["wall_s"] = time.perf_counter() - start
            problems = browser.problems()
            if problems:
                raise RuntimeError(f"the page reported: {problems}")
    finally:
        server.send_signal(2)
        server.wait(30)
    return results


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], allow_abbrev=False)
    parser.add_argument("--work-dir", type=Path, default=ROOT / "out" / "viewer_latency")
    parser.add_argument("--moves", type=int, default=6)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "viewer_latency.json")
    args = parser.parse_args(argv)
    if CHROMIUM is None:
        raise SystemExit("needs Debian's chromium")
    from neuralbrdf.study.cost import machine

    results = {"machine": machine(), "load_average": {"before": list(os.getloadavg())}, "moves": args.moves}
    files = make_files(args.work_dir)
    results["files"] = {name: path.name for name, path in files.items()}
    results["server"] = server_times(files, args.moves)
    results["page"] = page_times(files, args.moves)
    results["load_average"]["after"] = list(os.getloadavg())
    args.out.write_text(json.dumps(results, indent=1) + "\n", encoding="utf-8")
    print(f"load average before {results['load_average']['before'][0]:.1f}, after {results['load_average']['after'][0]:.1f}")
    print(f"{'view':<12}{'server λ ms':>12}{'server Y ms':>12}{'page total ms':>15}{'server':>8}{'draw':>8}"
          f"{'CPU browser':>13}{'CPU server':>12}  redrawn")
    for view in DRIVERS:
        page = results["page"][view]
        draw = "-" if page["median_draw_ms"] is None else f"{page['median_draw_ms']:.0f}"
        print(f"{view:<12}{results['server']['views'][view + '/wavelength']['median_ms']:>12.1f}"
              f"{results['server']['views'][view + '/Y']['median_ms']:>12.1f}{page['median_total_ms']:>15.0f}"
              f"{page['median_server_ms']:>8.0f}{draw:>8}{page['browser_cpu_ms_per_update']:>13.0f}"
              f"{page['server_cpu_ms_per_update']:>12.0f}  {', '.join(page['views_redrawn'])}")
    print(f"-> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
