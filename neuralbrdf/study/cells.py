"""The cells of a study and their cache keys (docs/study.md).

A cell is one fit and its evaluation: ``(material, variant, plan, noise, seed)``, the plan by its
name (DS1..DS4, a plan file's stem: :class:`~neuralbrdf.study.profile.StabilitySpec`).  Its key hashes
everything that changes its result — the material's truth and table (file contents), the
variant's method, config file contents and overrides (with the contents of any ``--config`` overlay
among them; for NLB, the pretrained network's file
contents too; for ``auto``, the contents of its two candidates' configs and of the spectral NLB
candidate's pretrained network: :func:`auto_candidates`; for ``pca``, its basis file's contents:
:func:`pca_basis`), plan (a plan file's pairs, not its path:
an edited file reruns its cells, a moved one does not), noise, seed, and for the *main*
cell of a (material, variant) (DS1, no noise, seed 0: the one that is rendered and timed, unless the
variant is a sweep only — ``speed_accuracy: false``) the render and cost settings (the render
settings of every sweep cell too where the profile renders them, ``stability.render``) — so a finished cell is found again under ``DIR/cells/KEY/`` by a later
run with the same settings, and a changed config reruns only what it touches.

:func:`plan_cells` expands a profile: every variant on every material it applies to (the
spectral MLP needs spectral samples) as a main cell; for the stability variants every plan (DS1..DS4 and plan files) at
no noise and every noise level on DS1, at every seed (noise and plan sweeps need the virtual
instrument or an NBRDF proxy; a user's own table is fitted as it is); for grouped variants
(γ, angle unit, latent size) every seed at DS1 without noise.

**Seeds.** A cell's seed changes what :data:`SEEDING` says for its method — the spectral MLP's
initial weights and batch order, ABC's random starts — and, with noise, the noise drawn.  The
NLB latent fits take nothing random from the seed (screened starts from pretrained codes; the
RGB fit's full-batch steps, the spectral fit's subsets drawn from its config's ``data.seed``), nor
does ``auto`` (its ABC candidate's starts come from its ABC config's ``model.seed``, which no
``--model.*`` option of ``auto`` sets; its spectral NLB candidate is the spectral latent fit), nor
does ``pca`` (a closed-form ridge solve in a fixed basis), so
their noise-free cells run at seed 0 only: a spread over seeds that were all the same fit would
be no evidence of stability.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import yaml

from neuralbrdf.atomic import file_version
from neuralbrdf.configs_dir import overlay_base, resolve_config
from neuralbrdf.shipped import PRETRAINED_DEFAULT, PRETRAINED_DIR, SPECTRAL_DEFAULT, resolve_pretrained
from neuralbrdf.study.profile import Profile, VariantSpec

MAIN_PLAN, MAIN_NOISE, MAIN_SEED = "DS1", 0.0, 0
#: Bump when a cell's result format or computation changes: every cell reruns.
CELL_FORMAT = 4
#: Bump when the renders change: only rendered cells rerun (2: the preview scene's lights load in
#: file order, so model and truth share their paths; :func:`neuralbrdf.render.preview.load_scene`).
RENDER_FORMAT = 2


@dataclass(frozen=True)
class Seeding:
    """How a cell's seed enters a method's fit: the options that take it (``--seed_everything``
    is always given) and what it changes there; ``varies=None`` for a deterministic fit, with
    ``why`` it is."""

    args: tuple[str, ...]
    varies: str | None
    why: str = ""


#: Per method (module docstring, "Seeds"); written to ``study.json`` as ``seeding``.
SEEDING = {
    "spectral_mlp": Seeding((), "the network's initial weights and the order of its training batches "
                                "(--seed_everything)"),
    "abc": Seeding(("--model.seed",), "the random starts of the fit (--model.seed; the first start, the centre "
                                      "of the start box, is the same for every seed)"),
    "nlb": Seeding((), None, "the latent fit starts from screened pretrained codes and steps on the full batch "
                             "of every study plan"),
    "nlb_spectral": Seeding((), None, "the latent fit starts from screened codes and draws any subsets of samples "
                                      "its steps see from the config's data.seed"),
    "auto": Seeding((), None, "its ABC candidate's random starts come from its ABC config's model.seed, which no "
                              "option of the auto fit sets, and its spectral NLB candidate is the spectral NLB's "
                              "latent fit, which takes nothing random from the seed"),
    "pca": Seeding((), None, "the fit is a closed-form ridge solve of the samples in a fixed basis (the shipped "
                             "pca_basis.npz or the config's model.basis): nothing in it is random"),
}
#: What the seed changes in every cell with noise (:func:`neuralbrdf.study.cell.write_data`).
NOISE_SEEDING = "the measurement noise drawn"


def seeding_description(method: str) -> str:
    """What a cell's seed changes for ``method`` (``study.json``'s ``seeding``)."""
    seeding = SEEDING[method]
    if seeding.varies is None:
        return (f"nothing in a noise-free cell ({seeding.why}), so noise-free cells run at seed {MAIN_SEED} only; "
                f"with noise, {NOISE_SEEDING}")
    return f"{seeding.varies}; with noise also {NOISE_SEEDING}"


def seed_args(method: str, seed: int) -> list[str]:
    """The fit options (beyond ``--seed_everything``) that pass a cell's seed to ``method``'s fit."""
    return [word for option in SEEDING[method].args for word in (option, str(seed))]


def cell_seeds(profile: Profile, variant: VariantSpec, noise: float) -> tuple[int, ...]:
    """The seeds a variant's cells run at ``noise``: the stability seeds, or seed 0 alone where the
    seed changes nothing (a deterministic method without noise)."""
    if noise == 0.0 and SEEDING[variant.method].varies is None:
        return (MAIN_SEED,)
    return profile.stability.seeds


@dataclass(frozen=True)
class Cell:
    material: str
    variant: str
    plan: str
    noise: float
    seed: int

    @property
    def is_main(self) -> bool:
        return (self.plan, self.noise, self.seed) == (MAIN_PLAN, MAIN_NOISE, MAIN_SEED)

    @property
    def condition(self) -> str:
        """The condition label of the failure map: ``DS2``, ``DS1 3% noise``."""
        return self.plan + (f" {self.noise * 100:g}% noise" if self.noise else "")


def file_digest(path: str) -> str:
    """SHA-256 of a file's contents (``virtual:NAME`` stands for itself); a file is read again
    only when it changed (:func:`~neuralbrdf.atomic.file_version`)."""
    if path.startswith("virtual:"):
        return path
    return _digest(file_version(path))


@lru_cache(maxsize=None)
def _digest(version: tuple) -> str:
    return hashlib.sha256(Path(version[0]).read_bytes()).hexdigest()


def plan_digest(path: str) -> str:
    """SHA-256 of a plan file's pairs (signed in-plane angles rounded to the file's 1e-6°), in the
    file's order: what its cells measure, whatever the file's formatting; read again only when the
    file changed."""
    return _plan_digest(file_version(path))


@lru_cache(maxsize=None)
def _plan_digest(version: tuple) -> str:
    from neuralbrdf.data.plans import in_plane_plan

    pairs = np.round(np.stack(in_plane_plan(version[0]), axis=1), 6) + 0.0  # + 0.0: -0.0 is 0.0
    return hashlib.sha256(np.ascontiguousarray(pairs, dtype="<f8").tobytes()).hexdigest()


def flag_values(args, flag: str) -> list[str]:
    """The values given to ``flag`` in command-line ``args``, as ``FLAG VALUE`` or ``FLAG=VALUE``, in order."""
    args = list(args)
    values = []
    for i, arg in enumerate(args):
        if arg == flag and i + 1 < len(args):
            values.append(args[i + 1])
        elif arg.startswith(flag + "="):
            values.append(arg.split("=", 1)[1])
    return values


#: The default pretrained network of each method fitted on one (its file is part of a cell's key).
NETWORK_DEFAULTS = {"nlb": PRETRAINED_DEFAULT, "nlb_spectral": SPECTRAL_DEFAULT}


def pretrained_network(variant: VariantSpec) -> str | None:
    """The pretrained network an NLB variant fits on: ``--model.checkpoint`` of its arguments,
    else its config's ``model.init_args.checkpoint``, else the shipped default (``None``)."""
    given = flag_values(variant.args, "--model.checkpoint")
    if given:
        return given[0]
    config = yaml.safe_load(Path(variant.config).read_text()) or {}
    return ((config.get("model") or {}).get("init_args") or {}).get("checkpoint")


#: The ``auto`` fit's candidates: its ``model.init_args`` key naming each one's config, and the
#: config each defaults to (:class:`~neuralbrdf.lightning.auto_fit.AutoFitModule`).
AUTO_CANDIDATE_CONFIGS = {"abc": ("abc_config", "abc"), "nlb_spectral": ("nlb_spectral_config", "nlb_spectral")}


def _config_files(path) -> list[Path]:
    """A config file and the base it overlays (read first), those that exist."""
    path = resolve_config(path)
    if not Path(path).is_file():
        return []
    base = overlay_base(path)
    return [file for file in (base, Path(path)) if file is not None and Path(file).is_file()]


def _init_arg(files: list[Path], key: str):
    """``model.init_args.KEY`` as the last of ``files`` that sets it gives it, else ``None``."""
    value = None
    for file in files:
        model = (yaml.safe_load(Path(file).read_text(encoding="utf-8")) or {}).get("model") or {}
        init_args = (model.get("init_args") or {}) if isinstance(model, dict) else {}
        if isinstance(init_args, dict) and key in init_args:
            value = init_args[key]
    return value


def auto_candidates(variant: VariantSpec) -> dict:
    """What an ``auto`` variant's result depends on beyond its own config and arguments: the contents
    of each candidate's config (and the base it overlays; a file that does not exist is left out,
    the fit refuses it) and of the pretrained network its spectral NLB candidate fits on.  The
    candidate configs are named as the fit reads them: the variant's config, then its ``--config``
    overlays, then ``--model.abc_config`` / ``--model.nlb_spectral_config`` (the last wins)."""
    files = _config_files(variant.config) + [file for path in flag_values(variant.args, "--config")
                                             for file in _config_files(path)]
    digests, nlb_files = {}, []
    for candidate, (key, default) in AUTO_CANDIDATE_CONFIGS.items():
        named = (flag_values(variant.args, f"--model.{key}") or [None])[-1] or _init_arg(files, key) or default
        candidate_files = _config_files(named)
        digests[candidate] = [file_digest(str(file)) for file in candidate_files]
        if candidate == "nlb_spectral":
            nlb_files = candidate_files
    network = resolve_pretrained(_init_arg(nlb_files, "checkpoint"), SPECTRAL_DEFAULT)
    return {"configs": digests, "pretrained": file_digest(str(network)) if network.is_file() else str(network)}


#: The basis a ``pca`` fit reads unless told another (:data:`neuralbrdf.models.pca_brdf.BASIS_FILE`,
#: named here so that keying a cell imports no torch).
PCA_BASIS_DEFAULT = PRETRAINED_DIR / "pca_basis.npz"


def pca_basis(variant: VariantSpec) -> Path:
    """The basis file a ``pca`` variant fits in: the last ``--model.basis`` of its arguments, else
    its config's (or a ``--config`` overlay's) ``model.init_args.basis``, else the shipped one."""
    files = _config_files(variant.config) + [file for path in flag_values(variant.args, "--config")
                                             for file in _config_files(path)]
    named = (flag_values(variant.args, "--model.basis") or [None])[-1] or _init_arg(files, "basis")
    return Path(named) if named else PCA_BASIS_DEFAULT


def overlay_digests(variant: VariantSpec) -> list[str]:
    """Contents (digests) of the config files a variant's arguments add with ``--config``."""
    return [file_digest(str(resolve_config(path))) for path in flag_values(variant.args, "--config")]


#: The level-of-detail settings (section ``fast_paths``) a ``fast`` variant's fast paths are made with.
FAST_PATH_SETTINGS = "default"


def is_rendered(cell: Cell, profile: Profile) -> bool:
    """Whether ``cell`` is rendered and timed: the main condition of a speed–accuracy variant."""
    return cell.is_main and profile.variant(cell.variant).speed_accuracy


def renders_images(cell: Cell, profile: Profile) -> bool:
    """Whether ``cell``'s evaluation renders the preview scene (image metrics): a rendered main cell,
    and every cell of a stability variant where the profile renders the sweeps (``stability.render``)."""
    return is_rendered(cell, profile) or (profile.stability.render and cell.variant in profile.stability.variants)


def cell_settings(cell: Cell, profile: Profile) -> dict:
    """Everything a cell's result depends on (module docstring), as plain JSON values."""
    material = next(m for m in profile.materials if m.name == cell.material)
    variant = profile.variant(cell.variant)
    settings = {
        "format": CELL_FORMAT,
        "cell": asdict(cell),
        "material": {"name": material.name, "truth": file_digest(material.truth),
                     "table": None if material.table is None else file_digest(material.table)},
        "variant": {"method": variant.method, "config": file_digest(variant.config), "args": list(variant.args),
                    "render_variant": variant.render_variant},
    }
    if material.trust_units:  # only then, likewise: the keys of other materials stay what they were
        settings["material"]["trust_units"] = True
    overlays = overlay_digests(variant)
    if overlays:  # only then: the keys of variants without overlays stay what they were
        settings["variant"]["overlays"] = overlays
    seeded = seed_args(variant.method, cell.seed)
    if seeded:  # likewise: only the methods whose fit takes the seed as an option
        settings["variant"]["seed_args"] = seeded
    if variant.fast:  # only then: the keys of the other variants stay what they were
        settings["variant"]["fast"] = file_digest(str(resolve_config(FAST_PATH_SETTINGS, "lod")))
    if variant.method in NETWORK_DEFAULTS:  # a retrained network changes every NLB result
        network = resolve_pretrained(pretrained_network(variant), NETWORK_DEFAULTS[variant.method])
        settings["variant"]["pretrained"] = file_digest(str(network))
    if variant.method == "auto":  # an edited ABC or spectral NLB config, or a retrained network, changes its result
        settings["variant"]["candidates"] = auto_candidates(variant)
    if variant.method == "pca":  # a rebuilt basis changes every PCA result
        basis = pca_basis(variant)
        settings["variant"]["basis"] = file_digest(str(basis)) if basis.is_file() else str(basis)
    plan = profile.stability.plan(cell.plan)
    if plan != cell.plan:  # a plan file (only then: the keys of DS1..DS4 cells stay what they were)
        settings["plan"] = plan_digest(plan)
    settings["hemisphere_strata"] = list(profile.render.hemisphere_strata)
    if renders_images(cell, profile):
        settings["render"] = {**asdict(profile.render), "format": RENDER_FORMAT}
    if is_rendered(cell, profile):
        settings["cost"] = asdict(profile.cost)
    return settings


def cell_key(cell: Cell, profile: Profile) -> str:
    """Hex key of :func:`cell_settings` (24 characters of its SHA-256)."""
    text = json.dumps(cell_settings(cell, profile), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:24]


def applies(profile: Profile, material_name: str, variant_name: str) -> bool:
    """Whether a variant fits a material: one of its ``materials`` if it names them, and for the
    spectral MLP one with spectral samples."""
    material = next(m for m in profile.materials if m.name == material_name)
    variant = profile.variant(variant_name)
    if variant.materials is not None and material_name not in variant.materials:
        return False
    return variant.method != "spectral_mlp" or material.is_spectral


def plan_cells(profile: Profile) -> list[Cell]:
    """Every cell of ``profile`` once, main cells first (module docstring)."""
    cells: list[Cell] = []

    def add(cell: Cell) -> None:
        if cell not in cells:
            cells.append(cell)

    pairs = [(m, v) for m in profile.materials for v in profile.variants if applies(profile, m.name, v.name)]
    for material, variant in pairs:
        add(Cell(material.name, variant.name, MAIN_PLAN, MAIN_NOISE, MAIN_SEED))
    s = profile.stability
    for material, variant in pairs:
        sweeps = material.table is None
        if variant.name in s.variants:
            for seed in s.seeds:
                for plan in s.plans if sweeps else (MAIN_PLAN,):
                    if seed in cell_seeds(profile, variant, MAIN_NOISE):
                        add(Cell(material.name, variant.name, plan, MAIN_NOISE, seed))
                for noise in s.noise if sweeps else (MAIN_NOISE,):
                    if seed in cell_seeds(profile, variant, noise):
                        add(Cell(material.name, variant.name, MAIN_PLAN, noise, seed))
        if variant.group is not None:
            for seed in cell_seeds(profile, variant, MAIN_NOISE):
                add(Cell(material.name, variant.name, MAIN_PLAN, MAIN_NOISE, seed))
    return cells
