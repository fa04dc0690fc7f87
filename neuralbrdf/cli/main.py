"""The ``neuralbrdf`` command line: measure, calibrate, train, export, evaluate and study BRDF models.

Conventions (docs/formats.md#conventions): angles in degrees; in-plane files use *signed* angles ``theta_i,
theta_r`` in [-90, 90] with the mirror direction at ``theta_r = theta_i``; BRDF sample tables
use spherical ``theta_i, phi_i, theta_o, phi_o``; BRDF values in sr⁻¹ without cosine factor;
wavelengths in nm.  Every output is written atomically; bad input exits with status 2 and a
one-line reason naming the file, line and column (exit statuses: :mod:`neuralbrdf.errors`).
"""

from __future__ import annotations

import argparse
import sys

from neuralbrdf.atomic import command_inputs
from neuralbrdf.cli import commands
from neuralbrdf.console import clean_warnings
from neuralbrdf.data.plans import PLAN_HELP, PLAN_NAMES
from neuralbrdf.errors import (ENVIRONMENT_ERRNOS, EXIT_BAD_INPUT, EXIT_ENVIRONMENT, EXIT_OK, EnvironmentFailure,
                               InputError, Interrupted, error_line, exit_status)
from neuralbrdf.render import DEFAULT_VARIANT
from neuralbrdf.cli import acquisition_command, study_command, view_command

EPILOG = (
    "Conventions: angles in degrees. GCMS raw files hold signed in-plane angles theta_i, theta_r "
    "in [-90, 90] (wi = (sin ti, 0, cos ti), wo = (-sin tr, 0, cos tr); mirror at theta_r = theta_i) "
    "and the radiance factor beta at 390-730 nm every 10 nm. BRDF sample tables hold spherical "
    "theta_i, phi_i, theta_o, phi_o (theta in [0, 90], phi in [0, 360)), or signed in-plane "
    "theta_i_signed, theta_r_signed (in [-90, 90]), then R,G,B (linear sRGB) "
    "or one column per wavelength (nm), BRDF in 1/sr without cosine. Outputs: written whole or not at "
    "all; an output that is one of the command's inputs, a directory, device or FIFO is refused; a "
    "symbolic link is written through (the file it points to is replaced)."
)


#: Commands with their own argument parsers, handed the rest of the command line.
DELEGATED = {
    "train": "train, validate or test a model from a YAML config (neuralbrdf train --help; same as train.py)",
    "export": "export a trained checkpoint to one validated ONNX file (same as export/to_onnx.py)",
    "render": "render a model in the preview scene, or any scene that uses it (same as export/render.py)",
}


def _formatter(prog):
    return argparse.RawDescriptionHelpFormatter(prog, max_help_position=32)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="neuralbrdf",
        description=__doc__.split("\n\n")[0],
        epilog=EPILOG,
        formatter_class=_formatter,
        allow_abbrev=False,  # --ou is not --out: an abbreviation would change meaning as options are added
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, help_text in DELEGATED.items():  # parsed by their own commands (main)
        sub.add_parser(name, help=help_text, add_help=False)

    def add(name, func, help_text, description):
        p = sub.add_parser(name, help=help_text, description=description, epilog=EPILOG, formatter_class=_formatter,
                           allow_abbrev=False)
        if func is not None:
            p.set_defaults(func=func)
        return p

    acquisition_command.add_plan_arguments(add("plan", None, acquisition_command.PLAN_HELP,
                                               acquisition_command.PLAN_DESCRIPTION), PLAN_NAMES)

    p = add(
        "simulate",
        commands.simulate,
        "measure a virtual material with the virtual goniospectrophotometer",
        "Run the virtual GCMS instrument (docs/measure.md#the-virtual-goniospectrophotometer) on a stand-in material. Writes a GCMS raw file (radiance "
        "factor beta, 390-730 nm, including the instrument's lamp/detector response, which calibration against "
        "the munsell_n9 reference cancels), or with --truth the noiseless ground-truth spectral BRDF table "
        "(1/sr, 400-700 nm).",
    )
    p.add_argument("--material", required=True, help="cyan, magenta, gold, gonio or munsell_n9")
    p.add_argument("--plan", default="DS1", help="DS1 (default), DS2, DS3, DS4 or an in-plane plan file (CSV of "
                   "theta_i,theta_r, as 'neuralbrdf plan' writes)")
    p.add_argument("--noise", type=float, default=0.0, help="relative (multiplicative) noise, std dev (default 0)")
    p.add_argument("--noise-abs", type=float, default=0.0, help="additive noise on beta, std dev (default 0)")
    p.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    p.add_argument("--truth", action="store_true", help="write the noiseless ground-truth BRDF table instead")
    p.add_argument("--out", required=True, help="output CSV")

    p = add(
        "calibrate",
        commands.calibrate,
        "GCMS raw sample + Munsell N9 reference -> spectral BRDF table",
        "Calibrate a GCMS raw measurement against the Munsell N9 white measured at the same geometry "
        "(report Eq. 2.3: f = 0.79/pi * beta_sample / beta_munsell), trim 390-730 nm to 400-700 nm and write a "
        "spectral BRDF sample table (1/sr). Rows are matched by (theta_i, theta_r).",
    )
    p.add_argument("sample", help="GCMS raw CSV of the sample")
    p.add_argument("--reference", required=True, help="GCMS raw CSV of the Munsell N9 white")
    p.add_argument("--out", required=True, help="output BRDF table CSV")
    _trust_units(p)

    p = add(
        "to-rgb",
        commands.to_rgb,
        "spectral BRDF table -> linear sRGB BRDF table",
        "Convert a spectral BRDF table to linear sRGB (report Eq. 2.4 without the factor 100: CIE 1931 2° "
        "observer, D65, normalised so a flat spectrum c maps to about (c, c, c); IEC 61966-2-1 matrix).",
    )
    p.add_argument("table", help="spectral BRDF table CSV (spherical or signed in-plane)")
    p.add_argument("--out", required=True, help="output RGB BRDF table CSV, in the input's format")
    _trust_units(p)

    for name, help_text in (("sample", "sample a measured or virtual material on a plan"),
                            ("sample-nbrdf", "alias of sample (kept for NBRDF files)")):
        p = add(
            name,
            commands.sample,
            help_text,
            "Sample a material on a sampling plan and write a BRDF table (1/sr): a MERL measurement NAME.binary "
            "(Matusik et al. 2003; nearest cell, RGB), an RGL measurement NAME.bsdf (Dupuy & Jakob 2018; Mitsuba's "
            "measured plugin; spectral at 400-700 nm every 10 nm from a NAME_spec.bsdf, RGB from a NAME_rgb.bsdf, "
            "negative values clipped to 0; wi is the light), a MERL-proxy NBRDF network NAME.h5 with NAME.json beside "
            "it (Sztrajman et al. 2021; RGB) or virtual:NAME, the noiseless ground truth of a virtual stand-in "
            "(spectral, 400-700 nm).",
        )
        p.add_argument("material", help="NAME.binary, NAME.bsdf, NAME.h5 (or NAME.json) or virtual:NAME")
        p.add_argument("--plan", required=True, help=PLAN_HELP)
        p.add_argument("--out", required=True, help="output BRDF table CSV")

    p = add(
        "plot",
        commands.plot,
        "plot a BRDF table's in-plane slices (PNG, PDF or SVG)",
        "Plot a BRDF table (RGB or spectral; GCMS raw files need --reference) against the signed outgoing "
        "angle for a few incident angles, and the mirror-direction spectra of spectral tables.",
    )
    p.add_argument("table", help="BRDF table CSV, spherical or signed in-plane (or GCMS raw CSV with --reference)")
    p.add_argument("--reference", help="Munsell N9 GCMS raw CSV, when TABLE is a GCMS raw file")
    p.add_argument("--theta-i", type=float, nargs="+", help="incident angles to show (degrees, signed)")
    p.add_argument("--out", required=True, help="output figure: .png, .pdf or .svg")
    _trust_units(p)

    p = add(
        "demo",
        commands.demo,
        "the main job on the embedded default data",
        "Run the pipeline on the shipped virtual measurements: simulate (or reuse the shipped DS1 files), "
        "calibrate against the Munsell N9 reference, convert to linear sRGB and plot, for every stand-in.",
    )
    p.add_argument("--out-dir", default="out/demo", help="output folder (default out/demo)")
    p.add_argument("--material", nargs="+", default=None, help="materials (default: all four stand-ins)")
    p.add_argument("--overwrite", action="store_true", help="replace the outputs of an earlier demo in --out-dir "
                   "(without it, the command stops before any work when they exist)")

    p = add(
        "export-truth",
        commands.export_truth,
        "export a ground-truth material to an ONNX model file (kind 'reference')",
        "Write the ground truth of a material as one .onnx file under the model contract (docs/formats.md#onnx-model-files, docs/evaluate.md), so it "
        "renders through the same plugin, sampler and seeds as a fitted model. SOURCE is virtual:NAME (gold, gonio, "
        "cyan, magenta, munsell_n9: spectral, 400-700 nm, 1/sr), an NBRDF proxy NAME.h5 (linear sRGB, 1/sr), a "
        "MERL measurement NAME.binary (linear sRGB, 1/sr; MERL's nearest cell, unmeasured cells 0) or an RGL "
        "measurement NAME.bsdf (spectral 400-700 nm or linear sRGB as the file: Mitsuba's measured plugin resampled "
        "on a dense table, whose error against the plugin is measured, printed and written into the file).",
    )
    p.add_argument("source", help="virtual:NAME, an NBRDF weight file NAME.h5, a MERL file NAME.binary or an RGL "
                   "file NAME.bsdf")
    p.add_argument("--out", required=True, help="output .onnx file")

    p = add(
        "evaluate",
        commands.evaluate,
        "score a model file against a truth file (hemisphere, in-plane, rendered image)",
        "Score MODEL.onnx against TRUTH.onnx, or against an RGL measurement NAME.bsdf through Mitsuba's own "
        "measured plugin, which also renders its truth image (docs/evaluate.md): log-cosine and relative RMSE over 102 400 stratified "
        "hemisphere pairs (theta <= 80 deg), relative RMSE over the in-plane glossy (|ti - tr| <= 10 deg) and diffuse "
        "regions (1 deg grid within +-60 deg), and image metrics (relative MSE, PSNR, CIEDE2000 mean and p95) of both "
        "rendered in the material-preview scene (or your own, --scene) with the same seeds; the truth rendered again "
        "with other seeds gives the noise level. Spectral model and truth compare at 400-700 nm every 10 nm, otherwise "
        "in linear sRGB. The model's fast paths are scored against its f (and, when rendered, by the image they change). "
        "Writes DIR/evaluation.json, model.png, truth.png, error_map.png, comparison.png and prints a table.",
    )
    p.add_argument("model", help="model file (.onnx)")
    p.add_argument("--truth", required=True, help="truth file: .onnx (e.g. from export-truth), or an RGL measurement "
                   "NAME.bsdf, scored and rendered through Mitsuba's own measured plugin")
    p.add_argument("--out-dir", required=True, help="output folder")
    p.add_argument("--scene", default=None, help="render in this Mitsuba scene instead of the material preview: any "
                   "scene using the neuralbrdf BSDF; its material --material carries the model, then the truth")
    p.add_argument("--material", default=None, help="with --scene: the neuralbrdf material (its id, or the id of "
                   "its shape) to swap (default: the scene's only one)")
    p.add_argument("--variant", default=None, help=f"Mitsuba variant (default {DEFAULT_VARIANT}, as for render; with "
                   "a .bsdf truth the variant of its kind: llvm_ad_rgb for an RGB file)")
    p.add_argument("--backend", default="drjit", choices=("drjit", "onnxruntime"), help="plugin backend (default drjit)")
    p.add_argument("--spp", type=int, default=256, help="samples per pixel (default 256)")
    p.add_argument("--resolution", type=int, default=None, help="image width = height in pixels (default 128, or "
                   "the scene's own film with --scene)")
    p.add_argument("--seed", type=int, default=0, help="render seed (default 0)")
    p.add_argument("--fast", action="store_true",
                   help="render the model's fast path f_fast (neuralbrdf export --fast) and compare it with f too")
    p.add_argument("--no-render", action="store_true", help="direction metrics only (no Mitsuba)")

    study_command.add_arguments(add("study", study_command.run, study_command.HELP, study_command.DESCRIPTION))

    p = add(
        "ladder",
        commands.ladder,
        "make cheaper stand-ins of a model file (ABC fit, baked tables, distilled networks) with their error and cost",
        "Make the cost ladder of MODEL.onnx (docs/select.md): an ABC fit to the model's own dense samples, the model baked "
        "into tables over Rusinkiewicz angles (and wavelength) and, for spectral "
        "models, smaller spectral MLPs distilled from it, each a model file under the same contract recording its "
        "hemisphere log-cos RMSE against the parent and its measured Dr.Jit cost per query. Writes DIR/RUNG.onnx and "
        "DIR/ladder.json (together or not at all).",
    )
    p.add_argument("model", help="model file (.onnx)")
    p.add_argument("--out-dir", default=None, help="output folder (default: MODEL.ladder beside the model, where "
                   "'neuralbrdf select' looks first)")
    p.add_argument("--config", default="default", help="level-of-detail settings, section 'ladder' (default: the shipped "
                   "configs/lod/default.yaml)")
    p.add_argument("--tables", nargs="*", default=None, metavar="HxDxPxL",
                   help="node counts of the baked tables (theta_h x theta_d x phi_d x lambda; lambda ignored for RGB "
                        "models), e.g. 32x16x8x16; none: no table rungs (default: the config's ladder.tables)")
    p.add_argument("--students", nargs="*", default=None, metavar="LxH",
                   help="distilled spectral MLPs, hidden layers x units, e.g. 2x8 1x4; none: no students (default: "
                        "the config's ladder.students)")

    p = add(
        "select",
        commands.select,
        "pick per neuralbrdf material of a scene the cheapest ladder rung within an image tolerance",
        "For every neuralbrdf BSDF of SCENE.xml, render the scene at low resolution with that material swapped for each "
        "rung of its ladder (matched seeds, the others full) and compare with the all-full render (mean CIEDE2000); "
        "pick the cheapest combination whose summed contributions stay within --tolerance, using only rungs whose mean "
        "CIEDE2000 over the material's own pixels stays within --object-tolerance, and verify it. The sample "
        "count is raised until the seed-to-seed noise of these errors is at most select.noise_fraction of their bounds. Writes OUT (the scene "
        "pointing at the chosen rung files) and OUT with suffix .json.",
    )
    p.add_argument("scene", help="Mitsuba scene file with neuralbrdf BSDFs")
    p.add_argument("--out", required=True, help="output scene SELECTED.xml (SELECTED.json beside it)")
    p.add_argument("--config", default="default", help="level-of-detail settings, section 'select' (default: the shipped "
                   "configs/lod/default.yaml); the options below override its values")
    p.add_argument("--tolerance", type=float, default=None, help="bound on the whole image's mean CIEDE2000 (config: select.tolerance)")
    p.add_argument("--object-tolerance", type=float, default=None,
                   help="bound on each material's mean CIEDE2000 over the pixels it covers (config: "
                   "select.object_tolerance; null there: --tolerance)")
    p.add_argument("--ladder", nargs="+", default=[], help="ladder folders (default: MODEL.ladder beside each model)")
    p.add_argument("--variant", default=None, help="Mitsuba variant (config: select.variant)")
    p.add_argument("--resolution", type=int, default=None, help="width of the selection renders (config: select.resolution)")
    p.add_argument("--spp", type=int, default=None, help="starting samples per pixel, raised for noise (config: select.spp)")
    p.add_argument("--max-spp", type=int, default=None, help="largest samples per pixel (config: select.max_spp)")
    p.add_argument("--seed", type=int, default=None, help="first render seed (config: select.seed)")

    view_command.add_arguments(add("view", view_command.run, view_command.HELP, view_command.DESCRIPTION))
    acquisition_command.add_acquire_arguments(add("acquire", acquisition_command.acquire, acquisition_command.ACQUIRE_HELP,
                                                  acquisition_command.ACQUIRE_DESCRIPTION))

    p = add(
        "regenerate-default-data",
        commands.regenerate_default_data,
        "regenerate the shipped virtual DS1 measurements",
        "Re-simulate the DS1 GCMS raw files shipped as package data (four stand-ins + munsell_n9) with the "
        "instrument's documented default noise and seed.",
    )
    p.add_argument("--out-dir", default=None, help="folder (default: the package's data/default)")
    return parser


def _trust_units(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(commands.TRUST_UNITS_FLAG, action="store_true",
                        help="read the measurement as it is where its numbers look like a unit slip (angles in "
                        "radians, wavelengths in um or angstrom, values in percent or times a cosine; "
                        "docs/robustness.md)")


def _delegated(name: str):
    """The ``main(argv)`` of a command with its own parser (train: LightningCLI; export; render)."""
    if name == "train":
        def train(argv: list[str]) -> int:
            from neuralbrdf.lightning.train_precheck import refused_table

            refused = refused_table(argv)
            if refused is not None:
                return refused
            from neuralbrdf.lightning.run import main

            return main(argv)

        return train
    if name == "render":  # imports Mitsuba: only when asked for
        from neuralbrdf.cli import render_command

        return render_command.main
    from neuralbrdf.cli import export_command

    return export_command.main


def main(argv: list[str] | None = None) -> int:
    """The ``neuralbrdf`` command; returns the exit status (:mod:`neuralbrdf.errors`: 2 on bad input,
    3 when the machine could not write an output).  Warnings are printed as one line each
    (:func:`neuralbrdf.console.clean_warnings`)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    with clean_warnings():
        if argv and argv[0] in DELEGATED:
            return _delegated(argv[0])(argv[1:])
        return _run(build_parser().parse_args(argv))


def _run(args: argparse.Namespace) -> int:
    prog = f"neuralbrdf {args.command}"
    try:
        with command_inputs():
            status = args.func(args)  # a command that can fail after its work returns its exit status
    except (InputError, EnvironmentFailure, Interrupted) as error:
        print(error_line(prog, error), file=sys.stderr)
        return exit_status(error)
    except OSError as error:  # one that no reader or writer named: its file, if the OS gave one
        if error.errno in ENVIRONMENT_ERRNOS:
            error = EnvironmentFailure.of(error, error.filename, "cannot read or write")
        print(error_line(prog, error), file=sys.stderr)
        return EXIT_ENVIRONMENT if isinstance(error, EnvironmentFailure) else EXIT_BAD_INPUT
    return status or EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
