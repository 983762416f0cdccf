"""toy: the reader and verify's render items (Lambert times the albedo, drawn as q)."""

from __future__ import annotations

import numpy as np

from sssbake.exporters import gltf_tables, usd
from sssbake.pipeline.render.items import PLAIN_ALBEDO
from sssbake.pipeline.techniques.technique import VerifyUnit


class ToyVerify:
    draw = None

    def read(self, path) -> dict:
        document = gltf_tables.load_sssbake_gltf(path, required=True)
        return {(i, j): np.asarray(tables["albedo"]) for i, mesh in enumerate(document.gltf.meshes)
                if (tables := gltf_tables.technique_tables(document, "meshes", i, "toy")) is not None
                for j in range(len(mesh.primitives))}

    def read_usd(self, path) -> dict:
        from pxr import Usd

        stage = Usd.Stage.Open(str(path))
        return {str(prim.GetPath()): np.asarray(tables["albedo"]) for prim in stage.Traverse()
                if (tables := usd.technique_tables(prim, "toy")) is not None}

    def verify_items(self, unit: VerifyUnit, data: dict, runtime: dict) -> tuple[dict, dict]:
        albedo = data[(unit.mesh, unit.primitives[0])]
        return ({**unit.base, "q": unit.lambert_q(unit.primitive.normals) * albedo},
                {**unit.base, "albedo": PLAIN_ALBEDO})
