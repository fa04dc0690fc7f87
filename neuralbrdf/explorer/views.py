"""The data of every view of the BRDF explorer, computed from the page's state.

The page holds a state (:data:`CONTROLS`: angles in degrees, wavelength in nm) and asks the
server for the views a change makes stale (:data:`VIEWS` lists what each view depends on).
:class:`Scene` computes a view's JSON payload from the state; each view is cached on the values
it depends on (:func:`depends`), so going back to a slider position costs nothing, and a view whose
values did not change is answered "unchanged" to a page that already shows it.

* ``inplane`` — ``f`` (or ``f·cos θi``) along a plane slice (:func:`~neuralbrdf.explorer.grids.plane_slice`)
  per model and the truth, and the measured samples at that ``θi`` when the plane is the plane of
  incidence (``φ = 0``);
* ``hemisphere`` — every outgoing direction at that ``θi`` (:func:`~neuralbrdf.explorer.grids.hemisphere_disk`):
  ``log10`` of the value and per model ``log10(model / truth)``, or the colour (linear sRGB scaled
  so its largest channel is 1: hue and saturation without brightness, sRGB-encoded);
* ``lobe`` — the same values on a ``θo × φo`` grid for the 3-D lobe (the page sets the radius);
* ``halfdiff`` — ``log10`` of the value on the ``θh × θd`` image at ``φd``, and per model
  ``log10(model / truth)``;
* ``sphere`` — the lit sphere (:func:`~neuralbrdf.explorer.grids.lit_sphere`): pixel = ``f · cos θi · E``
  with irradiance ``E = π · 2^EV`` (a white Lambertian surface facing the light shows ``2^EV``),
  either in colour (linear sRGB, clipped and sRGB-encoded as a display shows it; per model the
  CIEDE2000 map against the truth, :func:`neuralbrdf.evaluation.images.delta_e2000_map`) or at one
  wavelength (grey; per model ``log10(model / truth)``);
* ``spectrum`` — at the pair ``(θi, φi = 0)``, ``(θo, φo)`` picked: the spectrum of every spectral
  model (its whole range, 5 nm steps), the measured spectrum when a sample lies there, and the
  linear sRGB of every model.

Values a source cannot give (an RGB model at one wavelength) are left out and named under
``missing``.  Large arrays travel as base64 float32 in plotly.js's typed-array form
(``{"dtype": "f4", "bdata": ..., "shape": "H, W"}``).
"""

from __future__ import annotations

import base64
import dataclasses
import hashlib
import io
import math
import threading
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from neuralbrdf.errors import InputError
from neuralbrdf.evaluation.images import delta_e2000_map, displayed
from neuralbrdf.explorer import grids
from neuralbrdf.explorer.measured import Measured
from neuralbrdf.explorer.models import CHANNELS, ViewedModel
from neuralbrdf.geometry import spherical_to_vector

#: How the page names each channel (:data:`~neuralbrdf.explorer.models.CHANNELS`).
CHANNEL_LABELS = {"wavelength": "f at λ", "Y": "luminance Y", "R": "red", "G": "green", "B": "blue"}

#: The page's controls: ``name -> (label, unit, low, high, step)`` for numbers, ``(label, choices)``
#: for choices, each choice ``(value, label)``.
CONTROLS: dict[str, tuple] = {
    "theta_i": ("θi, incident polar angle", "°", 0.0, 89.0, 1.0),
    "wavelength": ("λ, wavelength", "nm", 360.0, 830.0, 5.0),
    "channel": ("quantity", tuple((channel, CHANNEL_LABELS[channel]) for channel in CHANNELS)),
    "cosine": ("value", (("f", "f"), ("f_cos", "f · cos θi"))),
    "plane_phi": ("φ, slice plane's azimuth from the plane of incidence", "°", 0.0, 180.0, 5.0),
    "hemisphere": ("map shows", (("value", "log₁₀ value"), ("colour", "colour (hue)"))),
    "phi_d": ("φd, difference azimuth", "°", 0.0, 180.0, 5.0),
    "light_theta": ("light, angle from the view direction", "°", 0.0, 89.0, 1.0),
    "light_phi": ("light, azimuth about the view direction", "°", 0.0, 360.0, 5.0),
    "exposure": ("exposure", "EV", -10.0, 10.0, 0.5),
    "sphere": ("sphere shows", (("colour", "colour (sRGB)"), ("wavelength", "f at λ (grey)"))),
    "pick_theta": ("picked θo", "°", 0.0, 89.0, 1.0),
    "pick_phi": ("picked φo", "°", 0.0, 360.0, 1.0),
}
#: The state each view is computed from.
VIEWS: dict[str, tuple[str, ...]] = {
    "inplane": ("theta_i", "plane_phi", "channel", "wavelength", "cosine"),
    "hemisphere": ("theta_i", "channel", "wavelength", "cosine", "hemisphere"),
    "lobe": ("theta_i", "channel", "wavelength", "cosine"),
    "halfdiff": ("phi_d", "channel", "wavelength", "cosine"),
    "sphere": ("light_theta", "light_phi", "exposure", "sphere", "wavelength"),
    "spectrum": ("theta_i", "pick_theta", "pick_phi", "cosine"),
}
#: Heat maps of ``log10`` values span at most this many decades below the top of their scale, which
#: is this percentile of their values.
LOG_DECADES = 4.0
LOG_PERCENTILE = 99.5
#: Wavelength step (nm) of the spectrum view.
SPECTRUM_STEP_NM = 5.0
#: Top of the ΔE2000 maps' colour scale (that of ``neuralbrdf evaluate``'s error map).
DELTA_E_MAX = 10.0
#: Views remembered per scene (each a few hundred kB at most).
CACHE_ENTRIES = 256


@dataclass(frozen=True)
class State:
    """The page's state (:data:`CONTROLS`); defaults as a page opens."""

    theta_i: float = 30.0
    plane_phi: float = 0.0
    wavelength: float = 550.0
    channel: str = "Y"
    cosine: str = "f"
    hemisphere: str = "value"
    phi_d: float = 90.0
    light_theta: float = 45.0
    light_phi: float = 135.0
    exposure: float = 0.0
    sphere: str = "colour"
    pick_theta: float = 30.0
    pick_phi: float = 180.0

    def updated(self, query: Mapping[str, str]) -> State:
        """This state with the entries of ``query`` (names of :data:`CONTROLS`, values as text),
        each checked against its control; :class:`InputError` naming the entry otherwise."""
        changes = {}
        for name, text in query.items():
            if name not in CONTROLS:
                continue
            control = CONTROLS[name]
            if len(control) == 2:
                values = [value for value, _ in control[1]]
                if text not in values:
                    raise InputError(f"expected one of {', '.join(values)}, got {text!r}", key=name)
                changes[name] = text
                continue
            try:
                value = float(text)
            except ValueError:
                raise InputError(f"expected a number ({control[1]}), got {text!r}", key=name) from None
            if not control[2] <= value <= control[3]:
                raise InputError(f"expected {control[2]:g} to {control[3]:g} {control[1]}, got {text}", key=name)
            changes[name] = value
        return dataclasses.replace(self, **changes)


def typed(array: np.ndarray) -> dict:
    """``array`` in plotly.js's typed-array form: float32, base64, its shape."""
    data = np.ascontiguousarray(array, dtype=np.float32)
    return {"dtype": "f4", "bdata": base64.b64encode(data.tobytes()).decode("ascii"),
            "shape": ", ".join(str(n) for n in data.shape)}


def listed(values: np.ndarray, digits: int = 5) -> list:
    """A 1-D array as a JSON list: ``digits`` significant digits, ``None`` where not finite."""
    return [float(f"{v:.{digits}g}") if math.isfinite(v) else None for v in np.asarray(values, dtype=np.float64)]


def png(rgba: np.ndarray) -> str:
    """A ``data:`` URI of an 8-bit PNG of ``rgba`` ``[H, W, 4]`` in [0, 1] whose row 0 is the image's
    bottom row (the chart's lowest ``y``)."""
    from matplotlib import image

    buffer = io.BytesIO()
    image.imsave(buffer, np.clip(rgba, 0.0, 1.0), format="png", origin="lower")
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


def log10(values: np.ndarray) -> np.ndarray:
    """``log10`` where positive, NaN elsewhere (a gap in a chart, not ``-inf``)."""
    values = np.asarray(values, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(values > 0, np.log10(np.where(values > 0, values, 1.0)), np.nan)


def log_range(*arrays: np.ndarray) -> list[float]:
    """``[low, high]`` of a colour scale shared by ``log10`` maps: from the 99.5th percentile of their
    values down at most :data:`LOG_DECADES` (a grazing spike of a few pixels does not flatten the rest)."""
    finite = np.concatenate([a[np.isfinite(a)].ravel() for a in arrays] + [np.zeros(0)])
    if not finite.size:
        return [-1.0, 1.0]
    high = float(np.percentile(finite, LOG_PERCENTILE))
    low = max(float(finite.min()), high - LOG_DECADES)
    return [low, high] if high > low else [high - 1.0, high + 1.0]


def hue(rgb: np.ndarray) -> np.ndarray:
    """Linear sRGB ``[N, 3]`` scaled so that the largest channel is 1 (black stays black)."""
    peak = rgb.max(axis=1, keepdims=True)
    return np.where(peak > 0, rgb / np.where(peak > 0, peak, 1.0), 0.0)


def rgba_image(image: grids.Image, linear_rgb: np.ndarray) -> np.ndarray:
    """The displayed colours (:func:`~neuralbrdf.evaluation.images.displayed`) of the image's pixels,
    transparent outside it."""
    colours = displayed(linear_rgb[:, None, :])[:, 0, :]
    return image.scatter(np.concatenate([colours, np.ones((len(colours), 1))], axis=1), fill=0.0)


def depends(name: str, state: State) -> tuple[str, ...]:
    """The controls view ``name`` depends on at ``state``: :data:`VIEWS` less those its modes ignore
    (the wavelength unless a view shows one wavelength; quantity and value in the colour map)."""
    ignored = set()
    shows_wavelength = state.sphere == "wavelength" if name == "sphere" else state.channel == "wavelength"
    if not shows_wavelength:
        ignored.add("wavelength")
    if name == "hemisphere" and state.hemisphere == "colour":
        ignored.update(("channel", "wavelength", "cosine"))
    return tuple(dep for dep in VIEWS[name] if dep not in ignored)


def sphere_radiance(source: ViewedModel, image: grids.Image, exposure_ev: float,
                    wavelength_nm: float | None = None) -> np.ndarray:
    """``[M, 3]`` pixel values of the lit sphere: ``f · cos θi · E``, ``E = π · 2^EV`` (module
    docstring), in linear sRGB, or at one wavelength (grey, the value in all three channels)."""
    irradiance = math.pi * 2.0**exposure_ev * np.clip(image.wi[:, 2], 0.0, None)
    if wavelength_nm is None:
        return source.linear_srgb(image.wi, image.wo) * irradiance[:, None]
    value = source.spectra(image.wi, image.wo, [wavelength_nm])[:, 0] * irradiance
    return np.repeat(value[:, None], 3, axis=1)


class Scene:
    """The models, the truth and the measurement a viewer shows, and the views of them."""

    def __init__(self, models: list[ViewedModel], truth: ViewedModel | None = None,
                 measured: Measured | None = None) -> None:
        if not models and truth is None:
            raise InputError("nothing to show: give a model file (or a truth)")
        self.models, self.truth, self.measured = models, truth, measured
        self.sources = models + ([truth] if truth is not None else [])
        spectral = [s for s in self.sources if s.is_spectral]
        self.wavelength_range_nm = ((min(s.model.wavelength_range_nm[0] for s in spectral),
                                     max(s.model.wavelength_range_nm[1] for s in spectral)) if spectral else None)
        channel = "wavelength" if spectral and len(spectral) == len(self.sources) else "Y"
        wavelength = float(np.clip(550.0, *self.wavelength_range_nm)) if spectral else 550.0
        self.defaults = State(channel=channel, wavelength=wavelength)
        self._cache: OrderedDict[tuple, dict] = OrderedDict()
        self._lock = threading.Lock()

    # ------------------------------------------------------------------ the page's questions

    def controls(self) -> dict:
        """The controls as the page builds them: label, unit, range, step, choices and default."""
        described = {}
        for name, control in CONTROLS.items():
            default = getattr(self.defaults, name)
            if len(control) == 2:
                choices = [list(c) for c in control[1] if self.wavelength_range_nm or c[0] != "wavelength"]
                described[name] = {"label": control[0], "choices": choices, "default": default}
            else:
                low, high = control[2], control[3]
                if name == "wavelength" and self.wavelength_range_nm:
                    low, high = self.wavelength_range_nm
                described[name] = {"label": control[0], "unit": control[1], "min": low, "max": high,
                                   "step": control[4], "default": default}
        if not self.wavelength_range_nm:
            del described["wavelength"]
        return described

    def describe(self) -> dict:
        """Everything the page needs before its first view: sources, measurement, controls, views."""
        measured = None
        if self.measured is not None:
            measured = {"label": self.measured.label, "file": self.measured.source, "rows": self.measured.n_rows,
                        "rows_out_of_plane": self.measured.n_dropped, "spectral": self.measured.is_spectral,
                        "theta_i": self.measured.incident_angles()}
        return {"sources": [s.describe() for s in self.sources], "measured": measured,
                "controls": self.controls(), "views": {name: list(deps) for name, deps in VIEWS.items()},
                "delta_e_max": DELTA_E_MAX}

    def view(self, name: str, state: State, known: str | None = None) -> dict:
        """The payload of view ``name`` at ``state`` (from the cache when it was computed before), with
        its ``key``: a digest of the values it depends on.  ``{"key": known, "unchanged": True}``
        when ``known`` is that key (the page already shows it)."""
        if name not in VIEWS:
            raise InputError(f"unknown view {name!r}; expected one of {', '.join(VIEWS)}", key="views")
        key = (name,) + tuple((dep, getattr(state, dep)) for dep in depends(name, state))
        digest = hashlib.blake2b(repr(key).encode(), digest_size=8).hexdigest()
        if digest == known:
            return {"key": digest, "unchanged": True}
        with self._lock:
            if key in self._cache:
                self._cache.move_to_end(key)
                return self._cache[key]
        payload = getattr(self, f"_{name}")(state)
        payload["key"] = digest
        with self._lock:
            self._cache[key] = payload
            while len(self._cache) > CACHE_ENTRIES:
                self._cache.popitem(last=False)
        return payload

    def forget(self) -> None:
        """Drop every remembered view (the next requests compute them again)."""
        with self._lock:
            self._cache.clear()

    # ------------------------------------------------------------------ helpers

    def _values(self, source: ViewedModel, wi, wo, state: State) -> np.ndarray | None:
        """A source's values in the state's channel, times ``cos θi`` when asked."""
        values = source.channel(wi, wo, state.channel, state.wavelength)
        if values is not None and state.cosine == "f_cos":
            values = values * np.clip(wi[:, 2], 0.0, None)
        return values

    def _missing(self, state: State, channel: str | None = None) -> list[str]:
        """The sources without values in ``channel`` (default the state's; ``colour``: linear sRGB)."""
        return [s.label for s in self.sources if not s.has(channel or state.channel)]

    # ------------------------------------------------------------------ views

    def _inplane(self, state: State) -> dict:
        theta_r, wi, wo = grids.plane_slice(state.theta_i, state.plane_phi)
        curves = []
        for source in self.sources:
            values = self._values(source, wi, wo, state)
            if values is not None:
                curves.append({"label": source.label, "role": source.role, "y": listed(values)})
        measured = None
        if self.measured is not None and state.plane_phi == 0.0:
            rows = self.measured.on_slice(state.theta_i)
            values = self.measured.channel(rows, state.channel, state.wavelength)
            if values is not None:
                if state.cosine == "f_cos":
                    values = values * math.cos(math.radians(state.theta_i))
                measured = {"label": self.measured.label, "x": listed(self.measured.theta_r[rows]), "y": listed(values)}
        return {"x": listed(theta_r), "curves": curves, "measured": measured, "missing": self._missing(state)}

    def _ratios(self, logs: dict[str, np.ndarray]) -> list[dict]:
        """Per model with a value, ``log10(model / truth)`` from the ``log10`` images ``logs``."""
        truth = logs.get(self.truth.label) if self.truth is not None else None
        if truth is None:
            return []
        return [{"label": m.label, "z": typed(logs[m.label] - truth)} for m in self.models if m.label in logs]

    def _hemisphere(self, state: State) -> dict:
        image = grids.hemisphere_disk(state.theta_i)
        maps, logs = [], {}
        for source in self.sources:
            if state.hemisphere == "colour":
                if not source.has("colour"):
                    continue
                rgb = source.linear_srgb(image.wi, image.wo)
                maps.append({"label": source.label, "png": png(rgba_image(image, hue(rgb)))})
                continue
            values = self._values(source, image.wi, image.wo, state)
            if values is not None:
                logs[source.label] = image.scatter(log10(values))
                maps.append({"label": source.label, "z": typed(logs[source.label])})
        axis = grids.disk_coordinates(grids.HEMISPHERE_SIZE)
        return {"axis": listed(axis), "maps": maps, "zrange": log_range(*logs.values()), "diffs": self._ratios(logs),
                "missing": self._missing(state, "colour" if state.hemisphere == "colour" else None)}

    def _lobe(self, state: State) -> dict:
        theta_o, phi_o, wi, wo = grids.lobe_grid(state.theta_i)
        surfaces = []
        for source in self.sources:
            values = self._values(source, wi, wo, state)
            if values is not None:
                surfaces.append({"label": source.label, "r": typed(values.reshape(len(theta_o), len(phi_o)))})
        return {"theta_o": listed(theta_o), "phi_o": listed(phi_o), "surfaces": surfaces,
                "incident": listed(wi[0]), "missing": self._missing(state)}

    def _halfdiff(self, state: State) -> dict:
        axis, image = grids.half_diff_image(state.phi_d)
        logs = {}
        for source in self.sources:
            values = self._values(source, image.wi, image.wo, state)
            if values is not None:
                logs[source.label] = image.scatter(log10(values))
        return {"axis": listed(axis), "zrange": log_range(*logs.values()),
                "maps": [{"label": label, "z": typed(z)} for label, z in logs.items()], "diffs": self._ratios(logs),
                "missing": self._missing(state)}

    def _sphere(self, state: State) -> dict:
        axis, image = grids.lit_sphere(state.light_theta, state.light_phi)
        colour = state.sphere == "colour" or self.wavelength_range_nm is None
        shaded = {}
        for source in self.sources:
            if source.has("colour" if colour else "wavelength"):
                shaded[source.label] = sphere_radiance(source, image, state.exposure,
                                                       None if colour else state.wavelength)
        images = [{"label": label, "png": png(rgba_image(image, rgb))} for label, rgb in shaded.items()]
        diffs = []
        truth = shaded.get(self.truth.label) if self.truth is not None else None
        for model in self.models if truth is not None else ():
            if model.label not in shaded:
                continue
            if colour:
                delta_e = delta_e2000_map(shaded[model.label][:, None, :], truth[:, None, :])[:, 0]
                diffs.append({"label": model.label, "z": typed(image.scatter(delta_e)), "kind": "delta_e2000",
                              "mean": float(delta_e.mean()), "p95": float(np.percentile(delta_e, 95))})
            else:
                ratio = log10(shaded[model.label][:, 0]) - log10(truth[:, 0])
                diffs.append({"label": model.label, "z": typed(image.scatter(ratio)), "kind": "log10_ratio"})
        missing = self._missing(state, "colour" if colour else "wavelength")
        return {"axis": listed(axis), "images": images, "diffs": diffs, "colour": colour, "missing": missing}

    def _spectrum(self, state: State) -> dict:
        wi = grids.incident(state.theta_i)[None, :]
        wo = spherical_to_vector(np.asarray(state.pick_theta), np.asarray(state.pick_phi))[None, :]
        cosine = max(float(wi[0, 2]), 0.0) if state.cosine == "f_cos" else 1.0
        curves, colours = [], []
        for source in self.sources:
            if source.has("colour"):
                colours.append({"label": source.label, "rgb": listed(source.linear_srgb(wi, wo)[0] * cosine),
                                "hue": listed(hue(source.linear_srgb(wi, wo))[0])})
            if source.is_spectral:
                low, high = source.model.wavelength_range_nm
                wavelengths = np.arange(low, high + 1e-9, SPECTRUM_STEP_NM)
                curves.append({"label": source.label, "x": listed(wavelengths),
                               "y": listed(source.spectra(wi, wo, wavelengths)[0] * cosine)})
        measured = None
        in_plane = min(abs(state.pick_phi - 180.0), abs(state.pick_phi), abs(state.pick_phi - 360.0)) <= 1e-6
        if self.measured is not None and self.measured.is_spectral and in_plane:
            theta_r = state.pick_theta if abs(state.pick_phi - 180.0) <= 1e-6 else -state.pick_theta
            row = self.measured.at_pair(state.theta_i, theta_r)
            if row is not None:
                measured = {"label": self.measured.label, "x": listed(self.measured.wavelengths),
                            "y": listed(self.measured.values[row] * cosine),
                            "theta_i": float(self.measured.theta_i[row]), "theta_r": float(self.measured.theta_r[row])}
        return {"curves": curves, "colours": colours, "measured": measured,
                "pair": {"theta_i": state.theta_i, "phi_i": 0.0, "theta_o": state.pick_theta, "phi_o": state.pick_phi}}
