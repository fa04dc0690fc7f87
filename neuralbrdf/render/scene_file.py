"""Any Mitsuba 3 scene file that uses the ``neuralbrdf`` BSDF (docs/mitsuba-plugin.md, docs/select.md): read, edit, render.

A user's scene names the plugin like any Mitsuba BSDF (see ``export/README.md``)::

    <bsdf type="neuralbrdf" id="gold">
        <string name="filename" value="models/gold.onnx"/>   <!-- relative to the scene file -->
        <string name="backend" value="drjit"/>                <!-- optional -->
    </bsdf>

:class:`SceneFile` holds the parsed XML so that commands can change it before Mitsuba loads it:
point a ``neuralbrdf`` BSDF at another model file (the selector's rungs) or replace it by an RGL
measurement (:meth:`SceneFile.set_measurement`, the truth of ``neuralbrdf evaluate --truth
NAME.bsdf``), set plugin properties
(``backend``, ``rgb_tolerance``), the film resolution or the integrator's ``max_depth``.
:func:`material_coverage` says which pixels each material covers (the level-of-detail
selector's per-object error, docs/select.md).
:meth:`SceneFile.load` loads the edited text with the scene's folder first on Mitsuba's file
resolver (as ``mi.load_file`` does), so relative paths in it — meshes, textures, included files,
model files — resolve as they would from the file itself.  It loads in file order, like the
preview scene (:data:`neuralbrdf.render.preview.FILE_ORDER_LOADING`: a fixed seed renders one image).

A scene whose model files are made by a command can say so in a scene parameter,
``<default name="neuralbrdf_models_command" value="bash export/lod_models.sh (from the repository
root)"/>`` (unused by Mitsuba): a missing model file is then reported with that command.

Materials are named by their ``id`` attribute, else the ``id`` of the shape that holds them, else
``neuralbrdf-K`` (K-th in document order).
"""

from __future__ import annotations

import contextlib
import copy
import time
import xml.etree.ElementTree as ElementTree
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from neuralbrdf.atomic import atomic_write, note_input
from neuralbrdf.errors import InputError
from neuralbrdf.limits import file_problem

PLUGIN = "neuralbrdf"
#: A scene parameter (``<default name=... value=.../>``) naming the command that makes the scene's
#: model files; the error for a missing model file quotes it.
MODELS_COMMAND = "neuralbrdf_models_command"
#: Largest scene file read (bytes); scenes reference meshes, they do not hold them.
MAX_SCENE_BYTES = 16 * 2**20


@dataclass(frozen=True)
class NeuralMaterial:
    """A ``neuralbrdf`` BSDF of a scene: its name, model file (resolved) and XML element."""

    name: str
    model: Path
    element: ElementTree.Element


class SceneFile:
    """A Mitsuba scene XML file, parsed and editable (module docstring)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise InputError(file_problem(self.path) or "no such scene file", path=self.path)
        if self.path.stat().st_size > MAX_SCENE_BYTES:
            raise InputError(f"scene file larger than {MAX_SCENE_BYTES} bytes", path=self.path)
        note_input(self.path)
        try:
            self.root = ElementTree.parse(self.path).getroot()
        except ElementTree.ParseError as error:
            raise InputError(f"not XML: {error}", path=self.path) from None
        if self.root.tag != "scene":
            raise InputError(f"the root element is <{self.root.tag}>, expected <scene>", path=self.path)
        self.folder = self.path.resolve().parent

    def copy(self) -> SceneFile:
        other = copy.copy(self)
        other.root = copy.deepcopy(self.root)
        return other

    # -- the neuralbrdf materials

    def materials(self) -> list[NeuralMaterial]:
        """Every ``neuralbrdf`` BSDF in document order (module docstring for the names)."""
        parents = {child: parent for parent in self.root.iter() for child in parent}
        found, names = [], set()
        for k, element in enumerate(e for e in self.root.iter("bsdf") if e.get("type") == PLUGIN):
            holder = parents.get(element)
            name = element.get("id") or (holder.get("id") if holder is not None and holder.tag == "shape" else None)
            name = name or f"{PLUGIN}-{k}"
            if name in names:
                raise InputError(f"two neuralbrdf materials are named {name!r}", path=self.path)
            names.add(name)
            filename = _property(element, "filename")
            if filename is None:
                raise InputError(f"neuralbrdf material {name!r} has no 'filename' property", path=self.path)
            model = self._resolve(filename.get("value", ""))
            if not model.is_file():
                command = self.expand(f"${MODELS_COMMAND}")
                made_by = "" if command.startswith("$") else f"; this scene's models are made by: {command}"
                raise InputError(f"the model file of neuralbrdf material {name!r} does not exist: {model}{made_by}",
                                 path=self.path)
            found.append(NeuralMaterial(name, model, element))
        return found

    def _resolve(self, filename: str) -> Path:
        path = Path(filename)
        return path if path.is_absolute() else (self.folder / path).resolve()

    def set_model(self, name: str, model: Path, properties: dict[str, str] | None = None) -> None:
        """Point material ``name`` at ``model`` (absolute path) and set string/float ``properties``."""
        material = next((m for m in self.materials() if m.name == name), None)
        if material is None:
            raise KeyError(name)
        _property(material.element, "filename").set("value", str(Path(model).resolve()))
        for key, value in (properties or {}).items():
            self.set_property(material.element, key, value)

    def set_measurement(self, name: str, measurement: Path, proposal: Path) -> None:
        """Replace material ``name`` by the RGL ``measurement`` (``.bsdf``) through Mitsuba's ``measured``
        plugin, sampled with ``proposal``'s proposal (the ``neuralbrdf_measured`` BSDF)."""
        from neuralbrdf.render.measured_bsdf import PLUGIN_NAME

        material = next((m for m in self.materials() if m.name == name), None)
        if material is None:
            raise KeyError(name)
        for child in list(material.element):
            material.element.remove(child)
        material.element.set("type", PLUGIN_NAME)
        for key, path in (("filename", measurement), ("proposal", proposal)):
            ElementTree.SubElement(material.element, "string", name=key, value=str(Path(path).resolve()))

    def set_all(self, key: str, value: str) -> None:
        """Set property ``key`` of every ``neuralbrdf`` material."""
        for material in self.materials():
            self.set_property(material.element, key, value)

    @staticmethod
    def set_property(element: ElementTree.Element, key: str, value: str) -> None:
        tag = {"rgb_tolerance": "float", "fast": "boolean", "rgb_head": "boolean"}.get(key, "string")
        existing = _property(element, key)
        if existing is not None:
            element.remove(existing)
        ElementTree.SubElement(element, tag, name=key, value=str(value))

    def expand(self, value: str) -> str:
        """``value`` with a ``$name`` scene parameter replaced by its ``<default>`` (if declared)."""
        if value.startswith("$"):
            default = next((d for d in self.root.iter("default") if d.get("name") == value[1:]), None)
            if default is not None:
                return default.get("value", value)
        return value

    # -- sensor and integrator

    def set_resolution(self, width: int, height: int | None = None) -> None:
        """Film size of every sensor (added where the film does not state it)."""
        films = [film for sensor in self.root.iter("sensor") for film in sensor.iter("film")]
        if not films:
            raise InputError("the scene has no <sensor> with a <film>; cannot set the resolution", path=self.path)
        for film in films:
            for key, value in (("width", width), ("height", height or width)):
                existing = _property(film, key)
                if existing is None:
                    existing = ElementTree.SubElement(film, "integer", name=key)
                existing.set("value", str(int(value)))

    def set_max_depth(self, max_depth: int) -> None:
        integrators = list(self.root.iter("integrator"))
        if not integrators:
            raise InputError("the scene has no <integrator>; cannot set max_depth", path=self.path)
        for integrator in integrators:
            existing = _property(integrator, "max_depth")
            if existing is None:
                existing = ElementTree.SubElement(integrator, "integer", name="max_depth")
            existing.set("value", str(int(max_depth)))

    # -- output

    def text(self) -> str:
        return ElementTree.tostring(self.root, encoding="unicode")

    def write(self, out: str | Path) -> None:
        """The edited scene as XML (atomically).  Relative paths in it stay relative to this scene's
        folder, so write it there (or use absolute paths)."""
        with atomic_write(out) as handle:
            handle.write(self.text() + "\n")

    def load(self, **parameters: str):
        """``mi.Scene`` of the edited text in the current variant (module docstring)."""
        import mitsuba as mi

        from neuralbrdf.render.load_time import validated_model
        from neuralbrdf.render.mitsuba_bsdf import scene_load_error
        from neuralbrdf.render.preview import FILE_ORDER_LOADING

        for material in self.materials():
            validated_model(material.model)  # one clear InputError (naming the file) before Mitsuba wraps it
        with _resolver_first(self.folder):
            try:
                return mi.load_string(self.text(), **FILE_ORDER_LOADING, **parameters)
            except RuntimeError as error:
                raise scene_load_error(error, self.path) from None


def _property(element: ElementTree.Element, name: str) -> ElementTree.Element | None:
    return next((child for child in element if child.get("name") == name), None)


@contextlib.contextmanager
def _resolver_first(folder: Path) -> Iterator[None]:
    """Mitsuba's file resolver with ``folder`` in front, restored afterwards."""
    import mitsuba as mi

    resolver = mi.file_resolver()
    saved = [str(resolver[i]) for i in range(len(resolver))]
    resolver.prepend(str(folder))
    try:
        yield
    finally:
        resolver.clear()
        for entry in saved:
            resolver.append(entry)


def uses_wavefront(scene_file: SceneFile) -> bool:
    """Whether a material of the scene uses the onnxruntime backend (which needs wavefront mode)."""
    return any((_property(m.element, "backend") is not None and
                _property(m.element, "backend").get("value") == "onnxruntime") for m in scene_file.materials())


def render_scene_file(scene_file: SceneFile, spp: int, seed: int = 0, spp_per_pass: int | None = None,
                      progress: bool = False, wavefront: bool = False) -> tuple[np.ndarray, float]:
    """``(linear RGB image [H, W, 3], seconds)`` of the edited scene in the current variant, rendered
    in passes like the preview (:func:`neuralbrdf.render.preview.render_passes`); the time counts the
    passes only, not loading the scene (which fits the samplers).  Dr.Jit's wavefront mode when
    ``wavefront`` or when a material uses the onnxruntime backend, else symbolic mode."""
    from neuralbrdf.render import preview

    if spp < 1:
        raise InputError(f"spp must be a positive integer, got {spp}")
    wavefront = wavefront or uses_wavefront(scene_file)
    scene = scene_file.load()
    width, height = scene.sensors()[0].film().size()
    per_pass = spp_per_pass or max(1, (preview.PASS_LANES_WAVEFRONT if wavefront else preview.PASS_LANES_SYMBOLIC)
                                   // int(width * height))
    start = time.perf_counter()
    try:
        image = preview.render_passes(scene, spp, per_pass, seed, wavefront, progress)
    except Exception as error:  # Mitsuba: RuntimeError from its core, plain Exception from its Python layer
        if type(error) not in (Exception, RuntimeError):  # ("No integrator specified!"); anything else is a bug
            raise
        reason = " ".join(str(error).split())[:300] or type(error).__name__
        raise InputError(f"cannot render the scene: {reason}", path=scene_file.path) from None
    return image, time.perf_counter() - start


#: Id given to a nested ``neuralbrdf`` BSDF without one while :func:`material_coverage` loads the scene.
_COVERAGE_TAG = "__neuralbrdf_coverage_{}"


def material_coverage(scene_file: SceneFile, subpixels: int = 4) -> dict[str, np.ndarray]:
    """Per ``neuralbrdf`` material, the fraction of each pixel (``[H, W]`` in [0, 1], the film of
    the scene's first sensor, rows top to bottom like a rendered image) that the camera sees on a
    shape with that material: ``subpixels``² camera rays per pixel on a regular grid (pixel
    centres of the sub-cells, the sensor's time and aperture centre), intersected with the scene
    in the current variant; a ray counts for the material of the first shape it hits.  Only what
    the camera sees directly counts, not a material's reflection in another object.  Shapes are
    matched to materials by the BSDF's id (a nested BSDF without one gets a temporary id)."""
    import mitsuba as mi

    if subpixels < 1:
        raise InputError(f"subpixels must be a positive integer, got {subpixels}")
    tagged = scene_file.copy()
    ids = {}
    for k, material in enumerate(tagged.materials()):
        if material.element.get("id") is None:
            material.element.set("id", _COVERAGE_TAG.format(k))
        ids[material.element.get("id")] = material.name
    scene = tagged.load()
    sensor = scene.sensors()[0]
    width, height = (int(v) for v in sensor.film().crop_size())
    n = subpixels
    index = np.arange(width * height * n * n)
    pixel, cell = index // (n * n), index % (n * n)
    x = (pixel % width + (cell % n + 0.5) / n) / width
    y = (pixel // width + (cell // n + 0.5) / n) / height
    rays, _ = sensor.sample_ray(mi.Float(0.0), mi.Float(0.5), mi.Point2f(mi.Float(x), mi.Float(y)),
                                mi.Point2f(0.5, 0.5))
    hit_shape = scene.ray_intersect(rays).shape
    coverage = {name: np.zeros((height, width)) for name in ids.values()}
    for shape in scene.shapes():
        bsdf = shape.bsdf()
        name = ids.get(bsdf.id()) if bsdf is not None else None
        if name is None:
            continue
        hits = np.asarray(hit_shape == mi.ShapePtr(shape), dtype=bool)
        coverage[name] += hits.reshape(height, width, n * n).mean(axis=2)
    return coverage
