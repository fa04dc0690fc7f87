"""The ``neuralbrdf view`` subcommand: arguments, one call into :func:`neuralbrdf.api.view` (the work is in
:mod:`neuralbrdf.explorer`), and what it prints."""

from __future__ import annotations

HELP = "explore model files, a truth and a measurement in the browser (a local web page)"
DESCRIPTION = (
    "Serve an interactive BRDF explorer on this machine and print its address as the first line of output: "
    "'serving http://HOST:PORT/'. Open it in a browser. The page evaluates every MODEL.onnx (any kind) and the "
    "--truth live: an in-plane (or any plane) slice at an incident angle with the --table samples lying in it, the "
    "whole hemisphere as a map and a 3-D lobe, the theta_h-theta_d image and its difference to the truth, a sphere "
    "lit by a movable directional light with its CIEDE2000 map against the truth, and for spectral models a "
    "wavelength slider, the spectrum at a picked direction pair and the sRGB colour of each direction. Angles in "
    "degrees, BRDF in 1/sr, wavelengths in nm. The truth must be a ground truth (kind 'reference', from "
    "'neuralbrdf export-truth'); spectral and RGB files mix (compared in linear sRGB). Ctrl-C stops the server "
    "(exit 0). Bad input (a missing or damaged file, a truth of another kind, a port in use) exits 2 before serving."
)


def add_arguments(parser) -> None:
    parser.add_argument("models", nargs="+", metavar="MODEL.onnx", help="model files (any kind, a truth too)")
    parser.add_argument("--truth", default=None, help="ground truth .onnx (kind 'reference', from export-truth)")
    parser.add_argument("--table", default=None, help="measurement to draw beside the models: a BRDF table CSV, a "
                        "GCMS raw CSV with --reference, or virtual:NAME (a shipped DS1 measurement)")
    parser.add_argument("--reference", default=None, help="Munsell N9 GCMS raw CSV, when --table is a GCMS raw file")
    parser.add_argument("--trust-units", action="store_true", help="read the --table as it is where its numbers look "
                        "like a unit slip (angles in radians, wavelengths in um, ...; docs/robustness.md)")
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this machine "
                        "only; anything else exposes the page to the network)")
    parser.add_argument("--port", type=int, default=0, help="port (default 0: a free one, printed)")


def run(args) -> int:
    """Check the files, bind, print the address, serve until Ctrl-C (exit 0; 130 when Ctrl-C comes
    while the files are still being checked)."""
    import sys

    from neuralbrdf import api
    from neuralbrdf.cli.commands import options
    from neuralbrdf.errors import InputError

    if args.reference is not None and args.table is None:
        raise InputError("--reference goes with a GCMS raw --table", key="--reference")
    try:
        with options():  # a unit slip in --table names --trust-units
            table = None if args.table is None else api.read(args.table, args.reference, trust_units=args.trust_units)
        viewer = api.view(*args.models, truth=args.truth, table=table, host=args.host, port=args.port, start=False)
    except KeyboardInterrupt:  # Ctrl-C while the files are checked: nothing was served
        print("neuralbrdf view: interrupted", file=sys.stderr)
        return 130
    try:
        print(f"serving {viewer.url}", flush=True)
        shown = ", ".join(f"{s.label} ({s.model.kind}{', truth' if s.role == 'truth' else ''})"
                          for s in viewer.scene.sources)
        print(f"showing {shown}{f'; measurement {args.table}' if args.table is not None else ''}; Ctrl-C stops",
              flush=True)
        if args.host not in ("127.0.0.1", "localhost", "::1"):
            print(f"neuralbrdf view: note: listening on {args.host}: other machines can open the page", file=sys.stderr)
        viewer.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        viewer.stop()
    print("stopped", flush=True)
    return 0
