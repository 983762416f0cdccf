"""Validation of a USD file: OpenUSD's validation framework plus the element counts USD leaves unchecked.

``UsdValidation`` runs every registered validator (usd-core has no ``usdchecker`` and no
``UsdUtils.ComplianceChecker``). It does not compare array lengths, so `mesh_problems` adds,
per ``UsdGeom.Mesh``: faceVertexCounts summing to the number of faceVertexIndices, indices in
range, finite points, and every primvar's (and ``normals``') element count against its
interpolation × elementSize; these are reported as validator ``sssbake:MeshChecker``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np
from pxr import Tf, Usd, UsdGeom, UsdValidation

from sssbake.pipeline.mesh.load_usd import usd_error_message

MESH_CHECKER = "sssbake:MeshChecker"


@dataclass(frozen=True)
class UsdValidationReport:
    """The validators' verdict on one file.

    Attributes
    ----------
    uri : str
    errors, warnings, infos : tuple of str
        One line each: ``"<validator>: <message> [at <site>, ...]"``.
    """

    uri: str
    errors: tuple[str, ...] = field(default=())
    warnings: tuple[str, ...] = field(default=())
    infos: tuple[str, ...] = field(default=())

    @property
    def ok(self) -> bool:
        """No errors and no warnings."""
        return not self.errors and not self.warnings

    def to_json(self) -> dict:
        return {"uri": self.uri, "errors": list(self.errors), "warnings": list(self.warnings),
                "infos": list(self.infos)}


def validate_usd(path: str | os.PathLike) -> UsdValidationReport:
    """Validate one .usd/.usda/.usdc file.

    A file USD cannot open is reported as one error of validator ``sssbake:StageOpen``.
    """
    uri = os.fspath(path)
    try:
        stage = Usd.Stage.Open(os.fsencode(uri))  # bytes: a POSIX name need not be UTF-8, a str for USD must
    except Tf.ErrorException as e:
        return UsdValidationReport(uri, errors=(f"sssbake:StageOpen: {usd_error_message(e, uri)}",))
    return validate_stage(stage, uri)


def validate_stage(stage: Usd.Stage, uri: str = "") -> UsdValidationReport:
    """Validate an open stage (see `validate_usd`)."""
    validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
    errors, warnings, infos = [], [], []
    try:
        found = UsdValidation.ValidationContext(validators).Validate(stage)
    except Tf.ErrorException:
        # Validators that make an asset path of the layer's own (MissingReferenceValidator,
        # UsdzPackageValidator) fail on a file name no asset path holds (a control character or bytes
        # that are not UTF-8, which a POSIX name may have): the others run, and those are named as not run.
        found = []
        for validator in validators:
            try:
                found += UsdValidation.ValidationContext([validator]).Validate(stage)
            except Tf.ErrorException as e:
                warnings.append(f"{validator.GetMetadata().name}: not run: {usd_error_message(e, uri)}")
    bucket = {
        UsdValidation.ValidationErrorType.Error: errors,
        UsdValidation.ValidationErrorType.Warn: warnings,
        UsdValidation.ValidationErrorType.Info: infos,
    }
    for error in found:
        if error.GetType() not in bucket:
            continue
        validator = error.GetValidator()
        name = validator.GetMetadata().name if validator else error.GetName()
        sites = [_site(s) for s in error.GetSites() if s.IsValid()]
        where = f" [at {', '.join(sites)}]" if sites else ""
        bucket[error.GetType()].append(f"{name}: {' '.join(error.GetMessage().split())}{where}")
    errors += [f"{MESH_CHECKER}: {problem}" for problem in mesh_problems(stage)]
    return UsdValidationReport(uri, tuple(errors), tuple(warnings), tuple(infos))


def mesh_problems(stage: Usd.Stage) -> list[str]:
    """Array-length and range problems of every ``UsdGeom.Mesh`` on the stage, one line each."""
    time = Usd.TimeCode.EarliestTime()
    problems = []
    for prim in stage.Traverse(Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)):
        if not prim.IsA(UsdGeom.Mesh):
            continue
        mesh = UsdGeom.Mesh(prim)
        at = f" [at {prim.GetPath()}]"
        points = _array(mesh.GetPointsAttr().Get(time), np.float64).reshape(-1, 3)
        counts = _array(mesh.GetFaceVertexCountsAttr().Get(time), np.int64)
        indices = _array(mesh.GetFaceVertexIndicesAttr().Get(time), np.int64)
        n = len(points)
        if not np.all(np.isfinite(points)):
            problems.append(f"points has non-finite values{at}")
        if int(counts.sum()) != len(indices):
            problems.append(f"faceVertexCounts sum to {int(counts.sum())}, faceVertexIndices has {len(indices)}{at}")
        if indices.size and (indices.min() < 0 or indices.max() >= n):
            problems.append(f"faceVertexIndices outside [0, {n}){at}")
        expected = {
            UsdGeom.Tokens.constant: 1, UsdGeom.Tokens.uniform: len(counts), UsdGeom.Tokens.vertex: n,
            UsdGeom.Tokens.varying: n, UsdGeom.Tokens.faceVarying: len(indices),
        }
        normals = mesh.GetNormalsAttr()
        if normals.HasAuthoredValue():
            count = len(normals.Get(time))
            want = expected.get(mesh.GetNormalsInterpolation())
            if count != want:
                problems.append(f"normals has {count} elements, {mesh.GetNormalsInterpolation()} interpolation "
                                f"needs {want}{at}")
        for pv in UsdGeom.PrimvarsAPI(mesh).GetPrimvarsWithAuthoredValues():
            problems += _primvar_problems(pv, expected, time, at)
    return problems


def _primvar_problems(pv: UsdGeom.Primvar, expected: dict, time: Usd.TimeCode, at: str) -> list[str]:
    interpolation = pv.GetInterpolation()
    size = pv.GetElementSize()
    elements = expected.get(interpolation)
    name = pv.GetName()
    if elements is None:
        return [f"{name} has unknown interpolation {interpolation!r}{at}"]
    value = pv.Get(time)
    if not pv.GetTypeName().isArray or value is None:
        return []
    if pv.IsIndexed():
        indices = _array(pv.GetIndices(time), np.int64)
        problems = []
        if len(indices) != elements * size:
            problems.append(f"{name}:indices has {len(indices)} elements, {interpolation} interpolation × "
                            f"elementSize {size} needs {elements * size}{at}")
        if indices.size and (indices.min() < 0 or indices.max() >= len(value)):
            problems.append(f"{name}:indices outside [0, {len(value)}){at}")
        return problems
    if len(value) != elements * size:
        return [f"{name} has {len(value)} elements, {interpolation} interpolation × elementSize {size} "
                f"needs {elements * size}{at}"]
    return []


def _site(site: UsdValidation.ValidationErrorSite) -> str:
    if site.IsProperty():
        return str(site.GetProperty().GetPath())
    if site.IsPrim():
        return str(site.GetPrim().GetPath())
    layer = site.GetLayer()
    return layer.identifier if layer else "?"


def _array(value, dtype) -> np.ndarray:
    return np.zeros(0, dtype=dtype) if value is None else np.asarray(value, dtype=dtype)
