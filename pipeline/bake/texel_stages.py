"""A scattering mesh's thickness, atlas and thickness map: stages that read the mesh and the options
alone, so a child can make them beside the escape gain, the pilot and the techniques
(`bake.beside`).

None of them needs what those make, but the atlas needs to know whether the input's UVs may serve,
and that the plan decides: kernels need a charted atlas with gutters, so a bake where the plan
picks kernels charts one (`asset._bake_mesh`). The child guesses: the input's UVs may serve
unless kernels were asked for by name. Where the plan then picks kernels after all, the atlas and
its thickness map are made again in the bake's own process; the child's are dropped.

Per mesh the child makes the thickness first (the plan reads it), then the atlas, then the map.
What it did not deliver (it raised, or died, or no child could be forked) the bake's process
makes itself, in turn, as it did before: results and errors are the same either way.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np

from sssbake.pipeline.bake.beside import Beside
from sssbake.pipeline.bake.stages import (
    AtlasParams,
    StageRunner,
    ThicknessMapParams,
    ThicknessParams,
    atlas_stage,
    thickness_map_stage,
    thickness_stage,
)
from sssbake.pipeline.core.surface import Surface
from sssbake.pipeline.mesh.atlas import Atlas
from sssbake.pipeline.mesh.scene import Mesh
from sssbake.pipeline.mesh.thickness import ThicknessResult
from sssbake.pipeline.mesh.thickness_map import ThicknessMap
from sssbake.pipeline.options import BakeOptions

#: The stages made here, in the order the child makes them per mesh.
STAGES = ("thickness", "atlas", "thickness_map")


def miss_cap(surface: Surface) -> float:
    """Where a thickness ray that leaves the mesh is capped: the bounding-box diagonal (file units)."""
    return float(np.linalg.norm(np.ptp(surface.positions, axis=0)))


def atlas_params(options: BakeOptions, reuse_input: bool) -> AtlasParams:
    return AtlasParams(options.atlas_resolution, options.atlas_padding, reuse_input)


@dataclass(eq=False)
class TexelStages:
    """The texel stages of an asset's scattering meshes, begun beside the bake where it may fork.

    Attributes
    ----------
    runner : StageRunner
    options : BakeOptions
    versions : dict
        Stage versions (`asset.STAGE_VERSIONS`).
    meshes : dict
        Per scattering mesh's index, (mesh, welded surface, the mesh's stage key).
    guess : bool
        Whether the child's atlases may take the input's UVs.
    beside : Beside or None
        The child, while it runs.
    from_beside : set of int
        The meshes whose atlas came from the child (their thickness map may too).
    """

    runner: StageRunner
    options: BakeOptions
    versions: dict
    meshes: dict[int, tuple[Mesh, Surface, str]]
    guess: bool
    beside: Beside | None = None
    from_beside: set[int] = field(default_factory=set)

    @staticmethod
    def start(runner: StageRunner, options: BakeOptions, versions: dict,
              meshes: dict[int, tuple[Mesh, Surface, str]]) -> "TexelStages":
        """Begin the stages of `meshes` in a child beside the caller where one may be forked."""
        stages = TexelStages(runner, options, versions, meshes, "kernels" not in options.techniques)
        if meshes:
            stages.beside = Beside.start(stages._made_beside)
        return stages

    def thickness(self, mi: int) -> ThicknessResult:
        """Mesh `mi`'s per-vertex thickness."""
        got = self._adopted("thickness", mi)
        return got[0] if got is not None else self._thickness(mi, self.runner.run)[0]

    def atlas(self, mi: int, reuse_input: bool) -> tuple[Atlas, str]:
        """Mesh `mi`'s atlas and its key; the input's UVs only where `reuse_input`."""
        got = self._adopted("atlas", mi) if reuse_input == self.guess else None
        if got is None:
            return self._atlas(mi, reuse_input, self.runner.run)
        self.from_beside.add(mi)
        return got

    def thickness_map(self, mi: int, atlas: Atlas) -> ThicknessMap:
        """Mesh `mi`'s thickness map on `atlas`, the one `atlas` returned last."""
        got = self._adopted("thickness_map", mi) if mi in self.from_beside else None
        return got[0] if got is not None else self._thickness_map(mi, atlas, self.runner.run)[0]

    def close(self) -> None:
        """End the child, if any (at once where it is still making what is no longer needed)."""
        if self.beside is not None:
            self.beside.close()
            self.beside = None

    def _adopted(self, stage: str, mi: int) -> tuple[object, str] | None:
        if self.beside is None:
            return None
        return self.runner.adopt(stage, lambda: self.beside.take((stage, mi)))

    def _made_beside(self) -> Iterator[tuple[tuple[str, int], object]]:
        """The child's work: every mesh's stages, each on a runner of its own (`StageRunner.detached`)."""
        run = self.runner.detached
        for mi in self.meshes:
            yield ("thickness", mi), self._thickness(mi, run)
            atlas = self._atlas(mi, self.guess, run)
            yield ("atlas", mi), atlas
            yield ("thickness_map", mi), self._thickness_map(mi, atlas.value, run)

    def _thickness(self, mi: int, run: Callable):
        mesh, surface, key = self.meshes[mi]
        return run("thickness", self.versions["thickness"], key, ThicknessParams(self.options.thickness_rays),
                   thickness_stage, surface, [p.normals for p in mesh.primitives], miss_cap(surface))

    def _atlas(self, mi: int, reuse_input: bool, run: Callable):
        mesh, _, key = self.meshes[mi]
        return run("atlas", self.versions["atlas"], key, atlas_params(self.options, reuse_input), atlas_stage,
                   [(p.positions, p.faces, p.uvs) for p in mesh.primitives])

    def _thickness_map(self, mi: int, atlas: Atlas, run: Callable):
        mesh, surface, key = self.meshes[mi]
        params = ThicknessMapParams(atlas_params(self.options, atlas.input_uv_set is not None),
                                    self.options.thickness_rays)
        return run("thickness_map", self.versions["thickness_map"], key, params, thickness_map_stage, atlas,
                   [(p.positions, p.normals) for p in mesh.primitives], surface, miss_cap(surface))
