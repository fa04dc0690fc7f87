"""Study profiles: which materials, model variants and conditions ``neuralbrdf study`` runs (docs/study.md).

A profile is a YAML file (``configs/study/quick.yaml``, ``full.yaml``, or a user's own)::

    render: {spp: 4, resolution: 32}           # evaluation renders (truth | model | ΔE)
    hemisphere_strata: [16, 20]                # optional: (cos θ, φ) strata of the hemisphere metrics
                                               # (default the evaluation's, 102 400 pairs; fewer is faster)
    cost: {spp: 4, resolution: 32, repeats: 2, batch: 65536}   # render-ratio and queries/s timing
    materials:
      - {name: gold, truth: virtual:gold}      # virtual instrument: any plan, any noise
      - {name: nylon, truth: merl-nbrdf/nylon.h5}                  # NBRDF proxy sampled on the plan
      - {name: alum, truth: merl/alum-bronze.binary}                # MERL measurement sampled on the plan
      - {name: felt, truth: rgl/acrylic_felt_green_spec.bsdf}       # RGL measurement: sampled, scored, rendered
                                                                    # through Mitsuba's measured plugin
      - {name: mine, table: my_measurement.csv, truth: mine_truth.onnx}   # a user's measured table
                                               # (spherical or signed in-plane; trust_units: true reads it
                                               # as it is where its numbers look like a unit slip)
    variants:                                  # every model variant: a config file + CLI overrides
      - {name: spectral_mlp, method: spectral_mlp, config: configs/spectral_mlp.yaml,
         args: [--trainer.max_epochs, "5"], group: "γ / angle unit", label: "γ=3 rad"}
    stability:
      variants: [spectral_mlp, abc]            # methods whose failures are mapped
      plans: [DS1, DS2, DS3, DS4, configs/plans/nlb_spectral_12.csv]   # names or plan files
      noise: [0.0, 0.01, 0.03, 0.1]            # relative, the virtual instrument's --noise
      seeds: [0, 1, 2, 3, 4]
      render: false                            # true: every sweep cell is rendered too (image ΔE2000)

Paths starting with ``configs/`` name the shipped configs (:mod:`neuralbrdf.configs_dir`), those
starting with ``../shared`` are relative to the repository root, others to the profile file.  ``method`` is ``spectral_mlp``, ``abc``, ``nlb``,
``nlb_spectral``, ``auto`` (ABC and the spectral NLB fitted side by side, the better on the measured pairs kept:
``configs/auto.yaml``) or ``pca`` (coefficients in a PCA basis of measured BRDFs, baked into a table:
``configs/pca.yaml``): which checkpoint is exported and what the cell's seed changes (every method takes the
material's samples as ``--data.path``); ``render_variant`` renders a model in another
Mitsuba variant (a spectral model in ``llvm_ad_rgb`` uses the reduced-wavelength rule).  Variants
with a ``group`` are also run at every stability seed (DS1, no noise) and box-plotted by ``label``.
``speed_accuracy: false`` makes a variant a sweep only: its DS1 noise-free seed-0 cell is neither
rendered nor timed, so it is no point of the speed–accuracy charts (the γ variants of the full
profile: the same 3×10 network as ``spectral_mlp``, so the same cost).  ``materials: [NAME, …]``
fits a variant to those materials only (default: every material it applies to).  ``fast: true``
studies the model's fast path instead of the model: each fitted model is exported with its
``f_fast`` (``neuralbrdf export --fast``, :mod:`neuralbrdf.lod.fast_paths`) and that output, cut
out as a model file of its own, is what the cell scores, renders and times.
A plan of ``stability.plans`` is DS1..DS4 or an in-plane plan file (:mod:`neuralbrdf.data.plans`:
the CSV of ``theta_i,theta_r`` pairs that ``neuralbrdf plan`` writes): ``configs/plans/NAME.csv``
names a shipped one, any other path is taken as the other paths are.  The file is read when the
profile is; its stem (``nlb_spectral_12``) names it in cells and the report, so two plans may not
share a name.  ``stability.render: true`` renders every cell of the sweeps as the main cells are
(only the main cells are timed), so the sweeps have image metrics too (the ``budget`` profile's
error against the number of measured pairs).
Every error names the profile file and the key (``materials[1].truth``): among others a virtual
material that does not exist, a truth ``.onnx`` that is not a valid ground truth (kind
``reference``, ``neuralbrdf export-truth``), render sizes outside what an evaluation accepts
(:data:`~neuralbrdf.evaluation.evaluate.MIN_RESOLUTION` to
:data:`~neuralbrdf.evaluation.evaluate.MAX_RESOLUTION`), more hemisphere pairs than
:data:`~neuralbrdf.evaluation.scores.MAX_HEMISPHERE_PAIRS` and a throughput batch above
:data:`~neuralbrdf.study.cost.MAX_BATCH`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import yaml

from neuralbrdf.configs_dir import CONFIGS_DIR, resolve_config
from neuralbrdf.data.plans import INPLANE_PLAN_COLUMNS, PLAN_NAMES, check_plan, in_plane_plan
from neuralbrdf.errors import InputError
from neuralbrdf.study.cost import MAX_BATCH
from neuralbrdf.evaluation.evaluate import MAX_RESOLUTION, MIN_RESOLUTION, REFERENCE_KIND
from neuralbrdf.evaluation.scores import HEMISPHERE_STRATA, check_strata
from neuralbrdf.virtual.materials import MATERIALS, VALIDATION_MATERIALS

METHODS = ("spectral_mlp", "abc", "nlb", "nlb_spectral", "auto", "pca")
BUILTIN_DIR = CONFIGS_DIR / "study"
REPO_ROOT = Path(__file__).resolve().parents[2]
MAX_NOISE = 1.0
#: The named plans a stability sweep takes (besides plan files): the instrument's in-plane plans.
SWEEP_PLANS = ("DS1", "DS2", "DS3", "DS4")


@dataclass(frozen=True)
class RenderSpec:
    spp: int
    resolution: int
    hemisphere_strata: tuple[int, int] = HEMISPHERE_STRATA


@dataclass(frozen=True)
class CostSpec:
    spp: int
    resolution: int
    repeats: int
    batch: int


@dataclass(frozen=True)
class MaterialSpec:
    """``truth``: ``virtual:NAME``, an NBRDF ``.h5``, a MERL ``.binary``, an RGL ``.bsdf`` or a reference ``.onnx``;
    ``table``: a user's own measurement (then plan and noise sweeps do not apply to it), read as it
    is with ``trust_units``."""

    name: str
    truth: str
    table: str | None = None
    trust_units: bool = False

    @property
    def is_virtual(self) -> bool:
        return self.truth.startswith("virtual:")

    @property
    def is_spectral(self) -> bool:
        """Whether its samples are spectral (virtual instrument, a spectral RGL file, or a user's table
        with wavelengths)."""
        if self.table is not None:
            from neuralbrdf.data.loading import read_brdf_table

            return read_brdf_table(self.table, self.trust_units).is_spectral
        if Path(self.truth).suffix == ".bsdf":
            from neuralbrdf.data.rgl_bsdf import RglBsdf

            return RglBsdf.load(self.truth).is_spectral
        return self.is_virtual


@dataclass(frozen=True)
class VariantSpec:
    name: str
    method: str
    config: str
    args: tuple[str, ...] = ()
    render_variant: str | None = None
    group: str | None = None
    label: str | None = None
    speed_accuracy: bool = True
    materials: tuple[str, ...] | None = None
    fast: bool = False


@dataclass(frozen=True)
class StabilitySpec:
    """``plans``: the names the cells know them by (DS1..DS4, a plan file's stem); ``plan_files``:
    the path each plan file's name stands for; ``render``: the sweep cells are rendered too."""

    variants: tuple[str, ...] = ()
    plans: tuple[str, ...] = ("DS1",)
    noise: tuple[float, ...] = (0.0,)
    seeds: tuple[int, ...] = (0,)
    plan_files: tuple[tuple[str, str], ...] = ()
    render: bool = False

    def plan(self, name: str) -> str:
        """What a plan's cells are measured on: the plan file a name stands for, else the name (DS1..DS4)."""
        return dict(self.plan_files).get(name, name)

    def pairs(self, name: str) -> int:
        """The number of direction pairs of the plan ``name`` (the main plan DS1 included)."""
        return len(in_plane_plan(self.plan(name))[0])


@dataclass(frozen=True)
class Profile:
    path: Path
    render: RenderSpec
    cost: CostSpec
    materials: tuple[MaterialSpec, ...]
    variants: tuple[VariantSpec, ...]
    stability: StabilitySpec = field(default_factory=StabilitySpec)

    def variant(self, name: str) -> VariantSpec:
        return next(v for v in self.variants if v.name == name)


def shipped_profiles() -> list[str]:
    """Names of the shipped profiles (``quick``, ``full``, ...): the YAML files of the shipped folder."""
    return sorted(path.stem for path in BUILTIN_DIR.glob("*.yaml"))


def resolve_profile_path(name_or_path: str) -> Path:
    """A shipped profile's name (:func:`shipped_profiles`) names its file; anything else is a YAML file."""
    if name_or_path in shipped_profiles():
        return BUILTIN_DIR / f"{name_or_path}.yaml"
    return Path(name_or_path)


class _Reader:
    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, key: str, message: str):
        raise InputError(message, path=self.path, key=key)

    def mapping(self, value, key: str, allowed: tuple[str, ...], required: tuple[str, ...] = ()) -> dict:
        if not isinstance(value, dict):
            self.fail(key, f"expected a mapping, got {type(value).__name__}")
        for name in value:
            if name not in allowed:
                self.fail(f"{key}.{name}" if key else str(name), f"unknown key; expected one of {', '.join(allowed)}")
        for name in required:
            if name not in value:
                self.fail(f"{key}.{name}" if key else name, "missing")
        return value

    def integer(self, value, key: str, low: int = 1, high: int | None = None) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or value < low or (high is not None and value > high):
            within = f">= {low}" if high is None else f"from {low} to {high}"
            self.fail(key, f"expected an integer {within}, got {value!r}")
        return value

    def truth(self, value, key: str) -> str:
        """A truth source: ``virtual:NAME`` of a shipped material, an NBRDF ``.h5``, a MERL ``.binary``, an RGL
        ``.bsdf`` or a ground truth ``.onnx``."""
        truth = self.file(value, key)
        if truth.startswith("virtual:"):
            if truth.split(":", 1)[1] not in (*MATERIALS, *VALIDATION_MATERIALS):
                self.fail(key, f"no virtual material {truth.split(':', 1)[1]!r}; expected one of "
                               f"{', '.join('virtual:' + name for name in (*MATERIALS, *VALIDATION_MATERIALS))}")
            return truth
        if Path(truth).suffix not in (".h5", ".binary", ".bsdf", ".onnx"):
            self.fail(key, "expected virtual:NAME, an NBRDF .h5, a MERL .binary, an RGL .bsdf or a reference .onnx")
        if Path(truth).suffix == ".bsdf":
            from neuralbrdf.data.rgl_bsdf import RglBsdf

            try:
                RglBsdf.load(truth)
            except InputError as error:
                self.fail(key, f"not a readable RGL measurement: {error.reason}")
        if Path(truth).suffix == ".onnx":
            from neuralbrdf.kinds import load_model

            try:
                kind = load_model(truth).kind
            except InputError as error:
                self.fail(key, f"not a valid model file: {error.reason}")
            if kind != REFERENCE_KIND:
                self.fail(key, f"is a {kind!r} model; a truth is a ground truth of kind {REFERENCE_KIND!r} "
                               "(neuralbrdf export-truth), not a fitted model")
        return truth

    def table(self, entry: dict, key: str) -> str:
        """A material's measured table (spherical or signed in-plane), read now: a file that is no
        BRDF table, or whose numbers look like a unit slip (unless ``trust_units``), fails here."""
        from neuralbrdf.data.loading import read_brdf_table
        from neuralbrdf.data.units import overridden_by

        table = self.file(entry["table"], f"{key}.table")
        trust_units = entry.get("trust_units", False)
        if not isinstance(trust_units, bool):
            self.fail(f"{key}.trust_units", f"expected true or false, got {trust_units!r}")
        try:
            with overridden_by(f"trust_units: true in {key}"):
                read_brdf_table(table, trust_units)
        except InputError as error:
            self.fail(f"{key}.table", str(error))
        return table

    def string(self, value, key: str) -> str:
        if not isinstance(value, str) or not value.strip():
            self.fail(key, f"expected a non-empty string, got {value!r}")
        return value

    def sequence(self, value, key: str) -> list:
        if not isinstance(value, list) or not value:
            self.fail(key, f"expected a non-empty list, got {value!r}")
        return value

    def plan(self, value, key: str) -> tuple[str, str | None]:
        """A plan of the stability sweep (module docstring): ``(name, None)`` for DS1..DS4,
        ``(stem, path)`` for an in-plane plan file, read now."""
        expected = f"expected {', '.join(SWEEP_PLANS)} or an in-plane plan file (CSV of {','.join(INPLANE_PLAN_COLUMNS)})"
        text = self.string(value, key)
        if text in SWEEP_PLANS:
            return text, None
        if Path(text).suffix.lower() != ".csv":
            self.fail(key, f"{expected}, got {text!r}")
        path = self.file(text, key, shipped_folder="plans")
        try:
            check_plan(path, in_plane=True)
        except InputError as error:
            self.fail(key, f"{expected}; {error}")
        if any(c.isspace() for c in Path(path).stem):  # a condition is the plan's name, a space, the noise
            self.fail(key, f"{path}: a plan file's name names its cells and conditions; expected one without spaces")
        return Path(path).stem, path

    def file(self, value, key: str, shipped_folder: str | None = None) -> str:
        """A file the profile names (module docstring), as an absolute path; ``shipped_folder``: a
        ``configs/`` path names a file of that shipped folder as it is (not a YAML config)."""
        text = self.string(value, key)
        if text.startswith("virtual:"):
            return text
        path = Path(text)
        if not path.is_absolute():
            if text.startswith(f"configs/{shipped_folder}/"):
                anchored = CONFIGS_DIR.joinpath(*path.parts[1:])
            elif text.startswith("configs/"):
                anchored = resolve_config(text)
            elif text.startswith("../shared"):
                anchored = REPO_ROOT / path
            else:
                anchored = self.path.parent / path
            path = anchored.resolve()
        if not path.is_file():
            self.fail(key, f"no such file {path}")
        return str(path)


def load_profile(name_or_path: str) -> Profile:
    """The validated profile (module docstring); :class:`InputError` naming file and key otherwise."""
    path = resolve_profile_path(name_or_path)
    if not path.is_file():
        raise InputError(f"no such study profile; expected {', '.join(shipped_profiles())} or a YAML file", path=path)
    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        raise InputError(f"not valid YAML ({getattr(error, 'problem', error)})", path=path,
                         row=None if mark is None else mark.line + 1) from None
    r = _Reader(path)
    raw = r.mapping(raw, "", ("render", "hemisphere_strata", "cost", "materials", "variants", "stability"),
                    ("render", "cost", "materials", "variants"))
    render = r.mapping(raw["render"], "render", ("spp", "resolution"), ("spp", "resolution"))
    cost = r.mapping(raw["cost"], "cost", ("spp", "resolution", "repeats", "batch"),
                     ("spp", "resolution", "repeats", "batch"))
    materials = []
    for i, entry in enumerate(r.sequence(raw["materials"], "materials")):
        key = f"materials[{i}]"
        entry = r.mapping(entry, key, ("name", "truth", "table", "trust_units"), ("name", "truth"))
        truth = r.truth(entry["truth"], f"{key}.truth")
        if Path(truth).suffix == ".onnx" and "table" not in entry:
            r.fail(f"{key}.table", "a truth given as .onnx needs the measured table to fit")
        table = r.table(entry, key) if "table" in entry else None
        materials.append(MaterialSpec(r.string(entry["name"], f"{key}.name"), truth, table,
                                      entry.get("trust_units", False)))
    variants = []
    for i, entry in enumerate(r.sequence(raw["variants"], "variants")):
        key = f"variants[{i}]"
        entry = r.mapping(entry, key, ("name", "method", "config", "args", "render_variant", "group", "label",
                                        "speed_accuracy", "materials", "fast"),
                          ("name", "method", "config"))
        if entry["method"] not in METHODS:
            r.fail(f"{key}.method", f"expected one of {', '.join(METHODS)}, got {entry['method']!r}")
        args = entry.get("args", [])
        if not isinstance(args, list) or not all(isinstance(a, (str, int, float)) for a in args):
            r.fail(f"{key}.args", "expected a list of command-line words")
        speed_accuracy, fast = entry.get("speed_accuracy", True), entry.get("fast", False)
        for name, value in (("speed_accuracy", speed_accuracy), ("fast", fast)):
            if not isinstance(value, bool):
                r.fail(f"{key}.{name}", f"expected true or false, got {value!r}")
        only = entry.get("materials")
        if only is not None:
            known = [m.name for m in materials]
            if not isinstance(only, list) or not only:
                r.fail(f"{key}.materials", f"expected a list of material names, got {only!r}")
            for j, name in enumerate(only):
                if name not in known:
                    r.fail(f"{key}.materials[{j}]", f"no material named {name!r} (the profile has {', '.join(known)})")
            only = tuple(only)
        variants.append(VariantSpec(
            r.string(entry["name"], f"{key}.name"), entry["method"], r.file(entry["config"], f"{key}.config"),
            tuple(str(a) for a in args), entry.get("render_variant"), entry.get("group"),
            entry.get("label") or entry["name"], speed_accuracy, only, fast))
    for names, what in (([m.name for m in materials], "materials"), ([v.name for v in variants], "variants")):
        duplicated = sorted({n for n in names if names.count(n) > 1})
        if duplicated:
            r.fail(what, f"duplicated names {duplicated}")
    strata = raw.get("hemisphere_strata", list(HEMISPHERE_STRATA))
    if not isinstance(strata, list) or len(strata) != 2:
        r.fail("hemisphere_strata", f"expected [n_cos, n_phi], got {strata!r}")
    strata = tuple(r.integer(n, f"hemisphere_strata[{i}]") for i, n in enumerate(strata))
    try:
        check_strata(strata)
    except InputError as error:
        r.fail("hemisphere_strata", error.reason)
    stability = StabilitySpec()
    if "stability" in raw:
        s = r.mapping(raw["stability"], "stability", ("variants", "plans", "noise", "seeds", "render"))
        for i, name in enumerate(s.get("variants", [])):
            if name not in [v.name for v in variants]:
                r.fail(f"stability.variants[{i}]", f"no variant named {name!r}")
        plans = [r.plan(plan, f"stability.plans[{i}]") for i, plan in enumerate(s.get("plans", ["DS1"]))]
        for i, (name, plan_file) in enumerate(plans):
            if plan_file is not None and name in PLAN_NAMES or any(
                    other == name and (other_file, plan_file) != (None, None) for other, other_file in plans[:i]):
                r.fail(f"stability.plans[{i}]", f"a second plan named {name!r} (a plan file is named by its stem, "
                                                f"which may not be another plan's name)")
        render_sweeps = s.get("render", False)
        if not isinstance(render_sweeps, bool):
            r.fail("stability.render", f"expected true or false, got {render_sweeps!r}")
        for i, noise in enumerate(s.get("noise", [0.0])):
            if isinstance(noise, bool) or not isinstance(noise, (int, float)) or not 0.0 <= noise <= MAX_NOISE:
                r.fail(f"stability.noise[{i}]", f"expected a relative noise in [0, {MAX_NOISE}], got {noise!r}")
        seeds = [r.integer(seed, f"stability.seeds[{i}]", 0) for i, seed in enumerate(s.get("seeds", [0]))]
        stability = StabilitySpec(tuple(s.get("variants", [])), tuple(dict.fromkeys(name for name, _ in plans)),
                                  tuple(float(n) for n in s.get("noise", [0.0])), tuple(seeds),
                                  tuple((name, plan_file) for name, plan_file in plans if plan_file is not None),
                                  render_sweeps)
    return Profile(
        path=path,
        render=RenderSpec(r.integer(render["spp"], "render.spp"),
                          r.integer(render["resolution"], "render.resolution", MIN_RESOLUTION, MAX_RESOLUTION), strata),
        cost=CostSpec(r.integer(cost["spp"], "cost.spp"), r.integer(cost["resolution"], "cost.resolution", 1, MAX_RESOLUTION),
                      r.integer(cost["repeats"], "cost.repeats"), r.integer(cost["batch"], "cost.batch", 1, MAX_BATCH)),
        materials=tuple(materials), variants=tuple(variants), stability=stability,
    )
