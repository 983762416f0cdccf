"""OpenPBR MaterialX document (``<stem>.mtlx``) of a BakedAsset's materials, written next to its .usdc.

usd-core, which `exporters.usd` writes with, has no MaterialX: no ``UsdMtlx`` file format (a reference
to a .mtlx fails with "Cannot determine file format") and no ``ND_open_pbr_surface_surfaceshader`` in
its Sdr registry (UsdValidation refuses an OpenPBR shader in the .usdc). So the OpenPBR surfaces are
this separate MaterialX 1.39 document, which each Material prim of the .usdc names
(``sss:materialx``, ``sss:materialx:material``) for a MaterialX-enabled USD build to bind.

Layout: per material of the scene, in its order, a ``surfacematerial`` node named as the .usdc's
Material prim (`usd.material_prim_names`) whose ``surfaceshader`` input connects to an
``open_pbr_surface`` node (``SR_<name>``, node definition ``ND_open_pbr_surface_surfaceshader``) with
inputs from the material's factors: ``base_color``, ``base_metalness``, ``specular_roughness``,
``specular_ior`` (when the material has an ior) and ``geometry_opacity`` (the base colour's alpha).
A translucent material's base colour, ior and opacity are its fallback's (`baked.Fallback`: R_d, the
material's ior, 1) and it gets the subsurface inputs of `engine_materials.openpbr_subsurface` at the
.usdc's scale (`usd.mm_per_unit`), so ``subsurface_radius`` is in file
units and equals the .usdc's ``sss:openpbr:subsurfaceRadius``. Textures and emission are not carried
(glTF's emissive factor has no luminance for OpenPBR's ``emission_luminance``), nor sssbake's baked
data: the document describes the medium for a renderer's own subsurface, not the bake's techniques.

Values are written with 9 significant digits, which every float32 (MaterialX's float) survives.
"""

from __future__ import annotations

import os
from pathlib import Path

import MaterialX as mx
import numpy as np

from sssbake.exporters.atomic import atomic_path
from sssbake.exporters.finite import check_finite, finite_number
from sssbake.exporters.usd import material_prim_names, mm_per_unit
from sssbake.pipeline.core.engine_materials import openpbr_subsurface
from sssbake.pipeline.mesh.baked import BakedAsset, check_material_references

#: The MaterialX standard library's node definition of an OpenPBR surface.
OPENPBR_NODEDEF = "ND_open_pbr_surface_surfaceshader"
#: Prefix of a material's shader node (MaterialX's own examples name shaders ``SR_<material>``).
SHADER_PREFIX = "SR_"


def to_document(asset: BakedAsset) -> mx.Document:
    """The asset's materials as an OpenPBR MaterialX document (the module docstring's layout).

    Raises
    ------
    ValueError
        A non-finite factor, or scattering for materials the scene lacks.
    """
    check_material_references(asset)
    doc = mx.createDocument()
    scale = mm_per_unit(asset)
    names = material_prim_names(asset.scene.materials)
    # shader names are unique among the material names too: one namespace per document
    taken = set(names)
    for m, (src, name) in enumerate(zip(asset.scene.materials, names)):
        what = f"material {src.name!r}"
        shader_name, k = SHADER_PREFIX + name, 1
        while shader_name in taken:
            shader_name, k = f"{SHADER_PREFIX}{name}_{k}", k + 1
        taken.add(shader_name)
        shader = doc.addNode("open_pbr_surface", shader_name, "surfaceshader")
        shader.setNodeDefString(OPENPBR_NODEDEF)
        for input_name, value in _inputs(src, asset.scattering.get(m), scale, what):
            _set(shader, input_name, value, what)
        doc.addMaterialNode(name, shader)
    return doc


def _inputs(src, scattering, mm_per_unit: float, what: str) -> list[tuple[str, float | list[float]]]:
    """(input name, float or 3 floats) of one material's open_pbr_surface."""
    inputs: list[tuple[str, float | list[float]]] = [
        ("base_metalness", src.metallic_factor),
        ("specular_roughness", src.roughness_factor),
    ]
    if scattering is None:
        inputs += [("base_color", list(src.base_color_factor[:3])), ("geometry_opacity", src.base_color_factor[3])]
        if src.ior is not None:
            inputs.append(("specular_ior", src.ior))
        return inputs
    fallback = scattering.fallback
    inputs += [("base_color", list(fallback.base_color)), ("specular_ior", fallback.ior), ("geometry_opacity", 1.0)]
    inputs += list(openpbr_subsurface(scattering.material, mm_per_unit).items())
    return inputs


def _set(node: mx.Node, name: str, value, what: str) -> None:
    """Author input `name` as ``float`` or ``color3`` from its value string: MaterialX's own
    formatting keeps 6 significant digits, which rounds float32 values."""
    values = np.atleast_1d(np.asarray(value, dtype=np.float64))
    check_finite(values, f"{what} {name}")
    if values.size == 1:
        node.addInput(name, "float").setValueString(f"{finite_number(values[0], f'{what} {name}'):.9g}")
    else:
        node.addInput(name, "color3").setValueString(", ".join(f"{v:.9g}" for v in values))


def validate_document(doc: mx.Document) -> None:
    """Check `doc` against MaterialX's standard libraries (node definitions, input names and types).

    A copy takes the libraries: the document itself stays free of them (MaterialX writes imported
    library elements unless told otherwise).

    Raises
    ------
    ValueError
        ``"MaterialX document is invalid: <MaterialX's messages>"``.
    """
    library = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), library)
    checked = doc.copy()
    checked.importLibrary(library)
    valid, message = checked.validate()
    if not valid:
        raise ValueError(f"MaterialX document is invalid: {message.strip()}")


def write_mtlx(asset: BakedAsset, path: str | os.PathLike) -> dict:
    """Write the asset's OpenPBR MaterialX document (`to_document`, validated) to `path`, atomically.

    Returns
    -------
    dict
        ``path``, ``bytes`` (file size) and ``materials`` (the surfacematerial names, per scene material).

    Raises
    ------
    ValueError
        As `to_document`, or the document fails `validate_document` (nothing is written then).
    """
    path = Path(path)
    doc = to_document(asset)
    validate_document(doc)
    with atomic_path(path) as tmp:
        tmp.write_text(mx.writeToXmlString(doc), encoding="utf-8")
    return {"path": str(path), "bytes": path.stat().st_size,
            "materials": [m.getName() for m in doc.getMaterialNodes()]}
