"""Pick, per object, the cheapest model a scene can use (docs/select.md): ``neuralbrdf select``.

For a Mitsuba scene whose ``neuralbrdf`` BSDFs have cost ladders (:mod:`neuralbrdf.lod.ladder`),
at a low resolution (``resolution`` wide) and matched seeds.  The settings are
``configs/lod/default.yaml``, section ``select`` (:mod:`neuralbrdf.lod.config`).

**Matched paths.**  A stand-in is rendered with its parent's sampling proposal (the plugin's
``proposal`` property).  The proposal does not change what a render converges to, only its
noise, so with the same seed the stand-in and the full scene trace the same paths (same
directions, same wavelengths) and differ only by the BSDF values along them: their image
difference is the stand-in's bias, and most of the Monte Carlo noise cancels.  (Rendered with
its own proposal, a stand-in's image differs from the full one by about the seed-to-seed noise
even where it is exact; at the sample counts a selection can afford that noise is far above a
tolerance of 1 ΔE.)  The written scene uses each stand-in's own proposal.

**Two bounds.**  Every CIEDE2000 map is summarised twice: its mean over the whole image (bound:
the tolerance ``T``) and, per material, its mean over the pixels that material covers, each
pixel weighted by the fraction of it the material covers (the *on-object* error; bound: the
object tolerance, default ``T``).  Coverage comes from
:func:`~neuralbrdf.render.scene_file.material_coverage`: camera rays on a sub-pixel grid
intersected with the scene (what the camera sees directly; a material's reflection in another
object is not its coverage).  The whole-image mean alone is diluted by an object's screen share:
a close-up sphere covering a fifth of the frame can differ by 3 ΔE on itself at a whole-image
mean of 0.6, which is visible.  An object that covers no pixel has no on-object error; only the
whole-image bound applies to it (it gets its cheapest rung).

1. **Noise.** At ``spp`` (doubling up to ``max_spp``) the all-full scene and the all-cheapest scene
   (every material on its cheapest rung) are rendered with two seeds.  The mean CIEDE2000 of the
   two all-full renders is the *render noise* (stated, not used); the difference between the
   all-cheapest scene's error at the one seed and at the other is the *estimate noise*, how far
   a measured error moves with the seed: for the whole-image mean and for each material's
   on-object mean.  The sample count grows until each is at most ``noise_fraction`` times its
   bound; the JSON states them and whether that was reached.
2. **Each rung's effect.** Per material and rung: the scene with that material on the rung and
   the others full, against the all-full render at the same seed: its whole-image mean ΔE2000
   is the rung's *error contribution*, its mean over the material's pixels the rung's on-object
   error.
3. **Choice.** Among the rungs whose on-object error is within the object tolerance (the full
   model always is), the combination (one rung per material) with the smallest summed relative
   cost (from the ladders) whose summed contributions stay within ``T`` (contributions add when
   materials cover different pixels, the common case; the verification catches the rest);
   exhaustive over the combinations (:func:`best_combination`).  The render times of step 2 are
   recorded but not used: each is the first render of a new material combination and includes
   compiling its kernels, so they do not measure savings.
4. **Verification.** The chosen scene against the all-full one at both seeds, both bounds (an
   object's on-object error now also carries the other stand-ins' changes it reflects).  While
   one is exceeded, a material moves to its next more expensive admissible rung: the stand-in
   with the largest on-object error among those over the object tolerance, else the stand-in
   with the largest contribution.  Then the all-full and the selected scene (own proposals) are
   timed in interleaved renders (the shortest of ``timing_repeats``: on a shared machine other
   processes only ever add time; Dr.Jit's default symbolic mode,
   after one compiling render each).

The error renders run in Dr.Jit's wavefront mode: a scene with one material swapped then reuses
the compiled kernels of the others (in symbolic mode every combination compiles its own kernel,
~15 s each on 2 cores).

Outputs (together or neither): ``SELECTED.xml``, the scene with each material pointing at its
chosen rung file and plugin properties (file paths rewritten relative to the output's folder),
and ``SELECTED.json``.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from neuralbrdf.atomic import atomic_paths, check_outputs
from neuralbrdf.errors import InputError
from neuralbrdf.evaluation.images import delta_e2000_map
from neuralbrdf.lod.ladder import FULL_RUNG, Ladder, Rung, embedded_ladder, file_sha256, read_ladder
from neuralbrdf.render.scene_file import SceneFile, material_coverage, render_scene_file

#: Default ladder folder of ``MODEL.onnx``: ``MODEL.ladder`` beside it.
LADDER_SUFFIX = ".ladder"
#: Most combinations the exhaustive choice enumerates.
MAX_COMBINATIONS = 200_000
#: Widest selection render (the selection measures at low resolution; the shipped width is 96).
MAX_RESOLUTION = 1024
#: Most camera rays of the coverage (pixels x ``coverage_subpixels``², each ~50 bytes while cast).
MAX_COVERAGE_RAYS = 2**24


@dataclass(frozen=True)
class SelectSettings:
    """What :func:`select` measures and how (values: ``configs/lod/default.yaml``, section ``select``)."""

    #: Bound on the whole-image mean CIEDE2000.
    tolerance: float
    #: Bound on each material's on-object mean CIEDE2000; ``None``: ``tolerance``.
    object_tolerance: float | None
    variant: str
    #: Width of the selection renders (height from the scene's aspect ratio).
    resolution: int
    spp: int
    max_spp: int
    #: The estimate noise (module docstring, step 1) must be at most this fraction of its bound.
    noise_fraction: float
    seed: int
    timing_repeats: int
    #: Camera rays per pixel side of :func:`~neuralbrdf.render.scene_file.material_coverage`.
    coverage_subpixels: int

    @property
    def object_bound(self) -> float:
        return self.tolerance if self.object_tolerance is None else self.object_tolerance

    def check(self) -> None:
        """:class:`InputError` for a setting no selection can run with."""
        if not 0 < self.tolerance < math.inf:
            raise InputError(f"--tolerance must be a finite number > 0, got {self.tolerance}")
        if not 0 < self.object_bound < math.inf:
            raise InputError(f"--object-tolerance must be a finite number > 0, got {self.object_tolerance}")
        for name in ("resolution", "spp", "max_spp", "timing_repeats", "coverage_subpixels"):
            if getattr(self, name) < 1:
                raise InputError(f"{name.replace('_', '-')} must be a positive integer, got {getattr(self, name)}")
        if self.resolution > MAX_RESOLUTION:
            raise InputError(f"resolution must be at most {MAX_RESOLUTION} (the selection renders at low resolution), "
                             f"got {self.resolution}")
        if self.seed < 0:
            raise InputError(f"seed must be a non-negative integer, got {self.seed}")
        if not 0 < self.noise_fraction <= 1:
            raise InputError(f"noise_fraction must be in (0, 1], got {self.noise_fraction}")


def default_ladder_dir(model: Path) -> Path:
    return model.with_name(model.stem + LADDER_SUFFIX)


def find_ladders(scene: SceneFile, extra_dirs: list[Path]) -> dict[str, Ladder | None]:
    """Per material name, the ladder whose parent has the model file's SHA-256: among
    ``extra_dirs`` and ``MODEL.ladder`` beside each model, else the model file's own fast path
    (:func:`~neuralbrdf.lod.ladder.embedded_ladder`; ``None``: no ladder, stays full)."""
    candidates = [read_ladder(d) for d in extra_dirs]
    found = {}
    for material in scene.materials():
        sha = file_sha256(material.model)
        own = default_ladder_dir(material.model)
        pool = candidates + ([read_ladder(own)] if (own / "ladder.json").is_file() else [])
        found[material.name] = next((ladder for ladder in pool if ladder.parent_sha256 == sha), None) \
            or embedded_ladder(material.model)
    return found


def film_aspect(scene: SceneFile) -> float:
    """Height / width of the scene's first film (Mitsuba's defaults 768 x 576 where unstated)."""
    for sensor in scene.root.iter("sensor"):
        for film in sensor.iter("film"):
            size = {child.get("name"): scene.expand(child.get("value", "")) for child in film if child.tag == "integer"}
            try:
                return float(size.get("height", 576)) / float(size.get("width", 768))
            except ValueError:
                raise InputError("the film's width/height are not numbers", path=scene.path) from None
    raise InputError("the scene has no <sensor> with a <film>", path=scene.path)


class _Renderer:
    """Renders choices ``{material: Rung}`` of the scene at the selection resolution.  Error renders
    (wavefront mode) are remembered by scene text, sample count and seed: the same combination
    at the same seed (e.g. the verification of a single stand-in, measured alone in step 2) is the
    same image and is not rendered twice."""

    def __init__(self, scene: SceneFile, settings: SelectSettings) -> None:
        self.base = scene.copy()
        width = settings.resolution
        self.base.set_resolution(width, max(1, round(width * film_aspect(scene))))
        self.renders = 0
        self.reused = 0
        self._images: dict[tuple, tuple[np.ndarray, float]] = {}

    def scene(self, choice: dict[str, Rung], parents: dict[str, Path] | None = None) -> SceneFile:
        """The scene with ``choice``; with ``parents``, stand-ins sample with their parent's proposal."""
        scene = self.base.copy()
        for name, rung in choice.items():
            if rung.name != FULL_RUNG:
                properties = dict(rung.properties)
                if parents is not None and rung.path != parents[name]:
                    properties["proposal"] = str(parents[name])
                scene.set_model(name, rung.path, properties)
        return scene

    def render(self, choice: dict[str, Rung], spp: int, seed: int, parents: dict[str, Path] | None = None,
               wavefront: bool = True) -> tuple[np.ndarray, float]:
        scene = self.scene(choice, parents)
        key = (scene.text(), spp, seed)
        if wavefront and key in self._images:
            self.reused += 1
            return self._images[key]
        self.renders += 1
        image, seconds = render_scene_file(scene, spp, seed, wavefront=wavefront)
        if not np.all(np.isfinite(image)):
            raise InputError("a render of the scene is not finite", path=self.base.path)
        if wavefront:
            self._images[key] = (image, seconds)
        return image, seconds


@dataclass(frozen=True)
class ImageError:
    """CIEDE2000 of a render against the all-full one: the whole-image mean and, per material, the
    mean over its pixels weighted by coverage (``None`` where it covers no pixel)."""

    whole: float
    on_object: dict[str, float | None]


def image_error(image: np.ndarray, reference: np.ndarray, coverage: dict[str, np.ndarray]) -> ImageError:
    delta = delta_e2000_map(image, reference)
    return ImageError(float(np.mean(delta)), {name: on_object_mean(delta, weights) for name, weights in coverage.items()})


def on_object_mean(delta_e: np.ndarray, coverage: np.ndarray) -> float | None:
    """Mean of ``delta_e`` [H, W] weighted by ``coverage`` [H, W]; ``None`` where the weights are all 0."""
    total = float(np.sum(coverage))
    return None if total == 0 else float(np.sum(delta_e * coverage) / total)


def _within(error: float | None, bound: float) -> bool:
    return error is None or error <= bound


def best_combination(options: dict[str, list[dict]], tolerance: float, object_tolerance: float | None = None) -> dict[str, dict]:
    """The rung per material with the smallest summed relative cost (each rung's cost from its
    ladder, relative to its full model) among the combinations whose summed error contributions
    are within ``tolerance``, using only rungs whose on-object error (``on_object_delta_e2000``,
    ``None``: the object covers no pixel) is within ``object_tolerance`` (default ``tolerance``);
    ties go to the smaller summed error.  The full rung has error 0, so a solution always exists;
    an object that covers nothing gets its cheapest rung."""
    bound = tolerance if object_tolerance is None else object_tolerance
    admissible = {name: [o for o in rungs if _within(o.get("on_object_delta_e2000"), bound)]
                  for name, rungs in options.items()}
    names = list(admissible)
    total = 1
    for name in names:
        total *= len(admissible[name])
    if total > MAX_COMBINATIONS:
        raise InputError(f"{total} rung combinations; at most {MAX_COMBINATIONS} are searched")
    best, best_key = None, None
    for combination in itertools.product(*(admissible[n] for n in names)):
        error = sum(o["error_contribution"] for o in combination)
        if error > tolerance:
            continue
        key = (round(sum(o["relative_cost"] for o in combination), 9), error)
        if best_key is None or key < best_key:
            best, best_key = combination, key
    return dict(zip(names, best))


def _over_bounds(errors: list[ImageError], names, settings: SelectSettings) -> tuple[dict, bool, list[str]]:
    """Of a verification at several seeds: each material's largest on-object error, whether the
    whole-image bound is exceeded at some seed, and the materials over the object bound."""
    on_object = {name: _largest([e.on_object[name] for e in errors]) for name in names}
    whole_over = max(e.whole for e in errors) > settings.tolerance
    return on_object, whole_over, [n for n, e in on_object.items() if not _within(e, settings.object_bound)]


def _worst_over(chosen: dict[str, dict], errors: list[ImageError], settings: SelectSettings) -> str | None:
    """The stand-in to move up after a failed verification (module docstring, step 4), ``None``
    when both bounds hold or no stand-in is left."""
    on_object, whole_over, objects_over = _over_bounds(errors, chosen, settings)
    if not whole_over and not objects_over:
        return None
    stand_ins = [n for n in chosen if chosen[n]["rung"] != FULL_RUNG]
    over = [n for n in objects_over if n in stand_ins]
    if over:
        return max(over, key=lambda n: on_object[n])
    return max(stand_ins, key=lambda n: chosen[n]["error_contribution"]) if stand_ins else None


def _largest(values: list[float | None]) -> float | None:
    present = [v for v in values if v is not None]
    return max(present) if present else None


def select(scene_path: str | Path, out_xml: str | Path, settings: SelectSettings,
           ladder_dirs: list[Path] | None = None, log=print) -> dict:
    """Run the selection (module docstring), write ``out_xml`` and the JSON beside it; return the JSON."""
    from neuralbrdf.render.preview import set_variant

    began, began_cpu = time.perf_counter(), time.process_time()
    settings.check()
    out_xml = Path(out_xml)
    if out_xml.suffix.lower() != ".xml":
        raise InputError("the output must be an .xml file (SELECTED.json is written beside it)", path=out_xml)
    out_json = out_xml.with_suffix(".json")
    scene = SceneFile(scene_path)
    check_outputs(out_xml, out_json)  # before the renders, not after them (the scene is an input now)
    materials = scene.materials()
    if not materials:
        raise InputError("the scene has no neuralbrdf material to select models for", path=scene.path)
    rays = settings.resolution * max(1, round(settings.resolution * film_aspect(scene))) * settings.coverage_subpixels**2
    if rays > MAX_COVERAGE_RAYS:
        raise InputError(f"resolution {settings.resolution} with {settings.coverage_subpixels}² coverage rays per "
                         f"pixel casts {rays} rays; at most {MAX_COVERAGE_RAYS}", path=scene.path)
    ladders = find_ladders(scene, list(ladder_dirs or []))
    full = {m.name: Rung(FULL_RUNG, m.model, "", 1.0, 0.0) for m in materials}
    parents = {m.name: m.model for m in materials}
    rgb_variant = "_rgb" in settings.variant
    candidates = {
        name: [] if ladder is None else [r for r in ladder.rungs[1:] if r.applies_in(rgb_variant)]
        for name, ladder in ladders.items()
    }
    cheapest = {name: min([full[name], *rungs], key=lambda r: r.relative_cost) for name, rungs in candidates.items()}
    set_variant(settings.variant)
    renderer = _Renderer(scene, settings)
    coverage = material_coverage(renderer.base, settings.coverage_subpixels)
    seeds = (settings.seed, settings.seed + 1)
    bound = settings.object_bound
    phases: dict[str, float] = {}

    def phase_done(name: str) -> None:  # wall seconds since the previous phase ended
        phases[name] = time.perf_counter() - began - sum(phases.values())

    phase_done("setup_and_coverage")

    # 1. noise
    spp = settings.spp
    while True:
        fulls = [renderer.render(full, spp, seed) for seed in seeds]
        cheaps = [renderer.render(cheapest, spp, seed, parents)[0] for seed in seeds]
        render_noise = float(np.mean(delta_e2000_map(fulls[0][0], fulls[1][0])))
        cheap_errors = [image_error(c, f[0], coverage) for c, f in zip(cheaps, fulls)]
        estimate_noise = abs(cheap_errors[0].whole - cheap_errors[1].whole)
        object_noise = {name: None if cheap_errors[0].on_object[name] is None else
                        abs(cheap_errors[0].on_object[name] - cheap_errors[1].on_object[name]) for name in coverage}
        largest_object_noise = _largest(list(object_noise.values())) or 0.0
        log(f"{spp} spp: render noise dE2000 {render_noise:.3f}; all-cheapest error {cheap_errors[0].whole:.3f} / "
            f"{cheap_errors[1].whole:.3f} at two seeds (estimate noise {estimate_noise:.3f}, on objects up to "
            f"{largest_object_noise:.3f})")
        noise_ok = (estimate_noise <= settings.noise_fraction * settings.tolerance
                    and largest_object_noise <= settings.noise_fraction * bound)
        if noise_ok or spp >= settings.max_spp:
            break
        spp = min(settings.max_spp, 2 * spp)
    reference = fulls[0][0]
    reference_s = min(seconds for _, seconds in fulls)  # the first render of a scene also compiles kernels
    phase_done("noise")

    # 2. each rung's effect
    options: dict[str, list[dict]] = {}
    for material in materials:
        options[material.name] = [{
            "rung": FULL_RUNG, "file": str(material.model), "kind": None, "relative_cost": 1.0,
            "bsdf_properties": {}, "hemisphere_logcos_rmse": 0.0, "error_contribution": 0.0,
            "on_object_delta_e2000": None if coverage[material.name].sum() == 0 else 0.0, "time_s": reference_s,
        }]
        if ladders[material.name] is None:
            log(f"{material.name}: no ladder for {material.model}; stays full")
            continue
        options[material.name][0]["kind"] = ladders[material.name].rungs[0].kind or None
        for rung in candidates[material.name]:
            image, seconds = renderer.render({**full, material.name: rung}, spp, settings.seed, parents)
            error = image_error(image, reference, coverage)
            on_object = error.on_object[material.name]
            options[material.name].append({
                "rung": rung.name, "file": str(rung.path), "kind": rung.kind, "relative_cost": rung.relative_cost,
                "bsdf_properties": dict(rung.properties), "hemisphere_logcos_rmse": rung.hemisphere_logcos_rmse,
                "error_contribution": error.whole, "on_object_delta_e2000": on_object, "time_s": seconds,
            })
            log(f"{material.name} -> {rung.name}: dE2000 {error.whole:.3f} (on the object "
                f"{'-' if on_object is None else f'{on_object:.3f}'}), {seconds:.2f} s (all full {reference_s:.2f} s; error renders, wavefront)")

    phase_done("rungs")

    # 3. choice, 4. verification
    chosen = best_combination(options, settings.tolerance, bound)
    while True:
        rung_of = {name: _rung(option, full[name]) for name, option in chosen.items()}
        verified = [image_error(renderer.render(rung_of, spp, seed, parents)[0], f[0], coverage)
                    for seed, f in zip(seeds, fulls)]
        described = ", ".join(f"{name}={option['rung']}" for name, option in chosen.items())
        log(f"selected {described}: dE2000 {verified[0].whole:.3f} / {verified[1].whole:.3f} at two seeds")
        worst = _worst_over(chosen, verified, settings)
        if worst is None:
            break
        dearer = [o for o in options[worst] if o["relative_cost"] > chosen[worst]["relative_cost"]
                  and _within(o["on_object_delta_e2000"], bound)]
        chosen[worst] = min(dearer, key=lambda o: o["relative_cost"]) if dearer else options[worst][0]
    on_object_verified, whole_over, objects_over = _over_bounds(verified, chosen, settings)
    within_bounds = not whole_over and not objects_over
    verified_whole = [e.whole for e in verified]
    if not within_bounds:  # only with every material full: two all-full renders at one seed disagreed
        log("warning: the selected scene is over a bound with no stand-in left to move up")
    phase_done("choice_and_verification")

    times: dict[str, list[float]] = {"full": [], "selected": []}
    for name, choice in (("full", full), ("selected", rung_of)):
        renderer.render(choice, spp, settings.seed + 2, wavefront=False)  # compiles the kernel
    for _ in range(settings.timing_repeats):
        for name, choice in (("full", full), ("selected", rung_of)):
            times[name].append(renderer.render(choice, spp, settings.seed + 2, wavefront=False)[1])
    reference_time, selected_time = min(times["full"]), min(times["selected"])
    phase_done("timing")

    result = {
        "scene": str(scene.path),
        "tolerance_delta_e2000": settings.tolerance,
        "object_tolerance_delta_e2000": bound,
        "materials": [
            {"name": name, "model": str(full[name].path), "chosen_rung": option["rung"], "file": option["file"],
             "kind": option["kind"], "bsdf_properties": option["bsdf_properties"],
             "error_contribution": option["error_contribution"],
             "on_object_delta_e2000": option["on_object_delta_e2000"],
             "on_object_delta_e2000_selected_scene": on_object_verified[name],
             "coverage_pixels": float(coverage[name].sum()),
             "cost": option["relative_cost"],
             "hemisphere_logcos_rmse": option["hemisphere_logcos_rmse"],
             "has_ladder": ladders[name] is not None}
            for name, option in chosen.items()
        ],
        "reference_time_s": reference_time,
        "selected_time_s": selected_time,
        "speedup": reference_time / selected_time,
        "image_delta_e2000_mean": max(verified_whole),
        "image_delta_e2000_mean_per_seed": verified_whole,
        "verified_within_bounds": within_bounds,
        "noise": {
            "render_seed_to_seed_delta_e2000_mean": render_noise,
            "estimate_seed_to_seed_delta_e2000": estimate_noise,
            "estimate_seed_to_seed_on_object_delta_e2000": object_noise,
            "all_cheapest_delta_e2000_per_seed": [e.whole for e in cheap_errors],
            "all_cheapest_on_object_delta_e2000_per_seed": [e.on_object for e in cheap_errors],
            "spp": spp,
            "estimate_noise_within_fraction_of_tolerance": noise_ok,
            "required_fraction": settings.noise_fraction,
            "method": "matched seeds and matched paths (stand-ins sample with their parent's proposal); render noise "
                      "= mean dE2000 between two all-full renders with different seeds; estimate noise = change of "
                      "the all-cheapest scene's error (whole image; on each object) between the two seeds",
        },
        "coverage": {
            "method": "camera rays on a regular sub-pixel grid intersected with the scene; a pixel's weight for a "
                      "material is the fraction of its rays whose first hit is a shape with that material "
                      "(directly seen only); on-object errors are coverage-weighted means of the dE2000 map",
            "subpixels_per_side": settings.coverage_subpixels,
            "pixels": int(reference.shape[0] * reference.shape[1]),
        },
        "render": {"variant": settings.variant, "width": settings.resolution, "aspect": film_aspect(scene),
                   "spp": spp, "seeds": list(seeds), "timing_repeats": settings.timing_repeats,
                   "timing_mode": "symbolic", "timing_statistic": "shortest of the repeats", "times_s": times},
        "candidates": options,
        "renders": renderer.renders,
        "renders_reused": renderer.reused,
        "selection_time_s": time.perf_counter() - began,
        # CPU seconds of all the process's threads: on an idle machine the wall time is at most about this
        # (CPU-bound work), whatever other processes did to selection_time_s.
        "selection_cpu_s": time.process_time() - began_cpu,
        "phase_times_s": phases,
        "settings": asdict(settings),
    }
    if not noise_ok:
        log(f"warning: the estimate noise (whole image {estimate_noise:.3f}, on objects up to {largest_object_noise:.3f}) "
            f"stayed above {settings.noise_fraction} x its bound at {spp} spp")
    selected = scene.copy()  # the user's film and settings, not the selection's
    for name, rung in rung_of.items():
        if rung.name != FULL_RUNG:
            selected.set_model(name, rung.path, dict(rung.properties))
    _relocate_paths(selected, out_xml.resolve().parent)
    with atomic_paths(out_xml, out_json) as (xml_tmp, json_tmp):
        xml_tmp.write_text(selected.text() + "\n")
        json_tmp.write_text(json.dumps(result, indent=2, allow_nan=False) + "\n")
    return result


def _rung(option: dict, full: Rung) -> Rung:
    if option["rung"] == FULL_RUNG:
        return full
    return Rung(option["rung"], Path(option["file"]), option["kind"], option["relative_cost"],
                option["hemisphere_logcos_rmse"], tuple(option["bsdf_properties"].items()))


def _relocate_paths(scene: SceneFile, folder: Path) -> None:
    """Rewrite the scene's file paths (``filename`` properties, ``<include>``) relative to ``folder``."""
    for element in scene.root.iter():
        attribute = "filename" if element.tag == "include" else ("value" if element.get("name") == "filename" else None)
        if attribute is None or element.get(attribute) is None or "$" in element.get(attribute):
            continue
        path = Path(element.get(attribute))
        absolute = path if path.is_absolute() else scene.folder / path
        element.set(attribute, os.path.relpath(absolute.resolve(), folder))
