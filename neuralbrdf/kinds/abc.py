"""Kind ``abc``: the ABC microfacet model (Löw et al. 2012, docs/models.md#abc) with fitted parameters.

The graph is :class:`~neuralbrdf.models.directional.AbcOnDirections` (RGB, or spectral with a
``wavelength`` input when the parameters have wavelengths).  Beside the graph the file stores
the parameters it implements, which the renderer reads to sample the analytic lobe (proposal
``abc_lobe``, :func:`neuralbrdf.render.sampling.fit_abc_mixture`):

=================================  ===========================================================
key                                value
=================================  ===========================================================
``neuralbrdf.abc.kd``              JSON list, diffuse albedo per channel (>= 0)
``neuralbrdf.abc.A``               JSON list, specular scale per channel (>= 0)
``neuralbrdf.abc.B``               distribution width B (>= 0)
``neuralbrdf.abc.C``               fall-off exponent C (>= 0)
``neuralbrdf.abc.eta``             index of refraction (> 0)
=================================  ===========================================================

``kd`` and ``A`` have one entry per RGB channel (3) for an RGB model, or one per wavelength of
the fit's grid for a spectral one (the sampler only uses their means).  Checkpoints come from
:class:`~neuralbrdf.lightning.abc_module.AbcModule` (``abc_parameters`` and ``material``).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from neuralbrdf.errors import InputError
from neuralbrdf.kinds import Exportable, Kind, contract_metadata, pick_material, provenance
from neuralbrdf.onnx_contract import kind_key, metadata_float, metadata_float_list
from neuralbrdf.physics.abc import AbcParameters

NAME = "abc"
KD_KEY = kind_key(NAME, "kd")
A_KEY = kind_key(NAME, "A")
B_KEY = kind_key(NAME, "B")
C_KEY = kind_key(NAME, "C")
ETA_KEY = kind_key(NAME, "eta")
KEYS = (KD_KEY, A_KEY, B_KEY, C_KEY, ETA_KEY)


@dataclass(frozen=True)
class AbcMetadata:
    """ABC parameters stored beside an ABC graph (docs/models.md#abc), used by its analytic sampler."""

    kd: tuple[float, ...]
    A: tuple[float, ...]
    B: float
    C: float
    eta: float

    def entries(self) -> dict[str, str]:
        """The file's ``neuralbrdf.abc.*`` metadata entries."""
        return {
            KD_KEY: json.dumps([float(v) for v in self.kd]),
            A_KEY: json.dumps([float(v) for v in self.A]),
            B_KEY: repr(float(self.B)),
            C_KEY: repr(float(self.C)),
            ETA_KEY: repr(float(self.eta)),
        }


def read_metadata(metadata: Mapping[str, str], path, is_spectral: bool) -> AbcMetadata:
    """The ABC parameters of a file's metadata, else :class:`InputError` naming the key."""
    missing = [key for key in KEYS if key not in metadata]
    if missing:
        raise InputError(f"ABC model lacks metadata keys {missing}", path=path)
    kd = metadata_float_list(metadata, KD_KEY, path)
    A = metadata_float_list(metadata, A_KEY, path)
    if not is_spectral:
        for key, values in ((KD_KEY, kd), (A_KEY, A)):
            if len(values) != 3:
                raise InputError(f"an RGB ABC model needs 3 values, found {len(values)}", path=path, key=key)
    if len(kd) != len(A):
        raise InputError(f"ABC kd has {len(kd)} channels but A has {len(A)}", path=path, key=A_KEY)
    B = metadata_float(metadata, B_KEY, path)
    C = metadata_float(metadata, C_KEY, path)
    eta = metadata_float(metadata, ETA_KEY, path)
    for key, value, ok, rule in ((B_KEY, B, B >= 0.0, ">= 0"), (C_KEY, C, C >= 0.0, ">= 0"), (ETA_KEY, eta, eta > 0.0, "> 0")):
        if not ok:
            raise InputError(f"metadata value {value!r} must be {rule}", path=path, key=key)
    return AbcMetadata(kd=kd, A=A, B=B, C=C, eta=eta)


def exportable(parameters: AbcParameters, material: str, provenance_text: str) -> Exportable:
    """The model of ABC ``parameters`` with its contract metadata, ready to export."""
    from neuralbrdf.models.directional import AbcOnDirections

    module = AbcOnDirections(parameters)
    wavelength_range = module.wavelength_range_nm if module.is_spectral else None
    stored = AbcMetadata(
        kd=tuple(parameters.kd.tolist()), A=tuple(parameters.A.tolist()), B=parameters.B, C=parameters.C, eta=parameters.eta
    )
    metadata = contract_metadata(
        NAME, material, provenance_text, wavelength_range_nm=wavelength_range, kind_metadata=stored.entries()
    )
    return Exportable(module, NAME, material, metadata, wavelength_range)


def from_checkpoint(checkpoint: dict, path: Path, material: str | None):
    for key in ("abc_parameters", "material"):
        if key not in checkpoint:
            raise InputError("ABC checkpoint lacks this key", path=path, key=key)
    parameters = AbcParameters.from_dict(checkpoint["abc_parameters"], source=str(path))
    name = pick_material([str(checkpoint["material"])], material, path)
    return exportable(parameters, name, provenance(checkpoint, path))


KIND = Kind(
    name=NAME,
    summary="the ABC microfacet model with fitted parameters, sampled analytically (docs/models.md#abc)",
    read_metadata=read_metadata,
    proposal="abc_lobe",
    from_checkpoint=from_checkpoint,
    recognises=lambda checkpoint: "abc_parameters" in checkpoint,
    scalar_parameters=3,  # B, C, eta (kd and A are weight tensors of the graph)
)
