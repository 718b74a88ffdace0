"""Write animated triangle meshes to a USD stage (time-sampled points)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hyperbones.errors import OutputError, ParameterError
from hyperbones.export._checks import check_positive, check_up
from hyperbones.export.scene_mesh import CheckedMesh, SceneMesh, checked_meshes
from hyperbones.io_utils import atomic_path, stated_reason

USD_SUFFIXES = (".usd", ".usda", ".usdc")


def write_usd(
    path: str | Path,
    meshes: list[SceneMesh],
    fps: float = 30.0,
    up_axis: str = "Z",
    meters_per_unit: float = 1.0,
) -> Path:
    """Write ``meshes`` to a USD stage at ``path`` (``.usd``/``.usdc`` binary, ``.usda`` text).

    The stage has an Xform ``/Root`` (the default prim) with one ``UsdGeom.Mesh`` per mesh.
    Animated meshes get ``points`` and ``extent`` time samples at time code = frame index
    0..T-1; static meshes a plain value. Stage metadata: ``startTimeCode`` 0,
    ``endTimeCode`` T-1, ``timeCodesPerSecond`` = ``framesPerSecond`` = ``fps``,
    ``upAxis``, ``metersPerUnit``. Faces are triangles (``faceVertexCounts`` all 3),
    ``subdivisionScheme`` "none".

    ``up_axis="Y"`` converts the Z-up input, (x,y,z) -> (x,z,-y); ``meters_per_unit``
    other than 1 rescales the metre input into the stage unit (points / meters_per_unit).
    All animated meshes must have the same number of frames. Written atomically; a stage that
    cannot be written (read-only folder, full disk) is an ``OutputError``.
    """
    from pxr import Sdf, Tf, Usd, UsdGeom

    path = Path(path)
    if path.suffix.lower() not in USD_SUFFIXES:
        raise ParameterError(f"{path}: the USD output must end in .usd, .usda or .usdc")
    fps = check_positive("fps", fps)
    up_axis = check_up(up_axis, "up_axis")
    meters_per_unit = check_positive("meters_per_unit", meters_per_unit)
    checked = _check_meshes(meshes, up_axis, meters_per_unit, Sdf)
    n_frames = max((m.points.shape[0] for m in checked if m.points.ndim == 3), default=1)

    with atomic_path(path) as tmp:
        stage = None
        try:
            stage = Usd.Stage.CreateNew(str(tmp))
            root = UsdGeom.Xform.Define(stage, "/Root")
            stage.SetDefaultPrim(root.GetPrim())
            UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z if up_axis == "Z" else UsdGeom.Tokens.y)
            UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
            stage.SetTimeCodesPerSecond(fps)
            stage.SetFramesPerSecond(fps)
            stage.SetStartTimeCode(0)
            stage.SetEndTimeCode(n_frames - 1)
            for mesh in checked:
                _define_mesh(stage, mesh)
            saved = stage.GetRootLayer().Save()
        except Tf.ErrorException as error:  # USD reports a file it cannot create or write in words
            why = stated_reason(str(error), path.parent)
            if why is None:
                raise
            raise OutputError(path, f"cannot write: {why}") from None
        finally:
            del stage  # release the layer before the file is renamed
        if not saved:
            raise OutputError(path, f"cannot write: {stated_reason('', path.parent) or 'USD did not save the stage'}")
    return path


def _check_meshes(meshes, up_axis: str, meters_per_unit: float, Sdf) -> list[CheckedMesh]:
    """``checked_meshes``, and each name a USD identifier."""
    for mesh in [meshes] if isinstance(meshes, SceneMesh) else list(meshes):
        name = getattr(mesh, "name", None)
        if isinstance(name, str) and not Sdf.Path.IsValidIdentifier(name):
            raise ParameterError(
                f"mesh name {name!r} is not a USD identifier (letters, digits, '_', not starting with a digit)")
    return checked_meshes(meshes, up_axis, meters_per_unit, "write_usd")


def _define_mesh(stage, mesh: CheckedMesh) -> None:
    """Author one ``UsdGeom.Mesh`` under /Root."""
    from pxr import Sdf, Usd, UsdGeom, Vt

    prim = UsdGeom.Mesh.Define(stage, f"/Root/{mesh.name}")
    n_faces = mesh.faces.shape[0]
    prim.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(n_faces, 3, dtype=np.int32)))
    prim.CreateFaceVertexIndicesAttr(
        Vt.IntArray.FromNumpy(np.ascontiguousarray(mesh.faces.ravel(), dtype=np.int32)))
    prim.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    prim.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)

    points_attr = prim.CreatePointsAttr()
    extent_attr = prim.CreateExtentAttr()
    if mesh.points.ndim == 2:
        points_attr.Set(Vt.Vec3fArray.FromNumpy(mesh.points))
        extent_attr.Set(Vt.Vec3fArray.FromNumpy(_extent(mesh.points)))
    else:
        lows = mesh.points.min(axis=1)
        highs = mesh.points.max(axis=1)
        for t in range(mesh.points.shape[0]):
            time = Usd.TimeCode(float(t))
            points_attr.Set(Vt.Vec3fArray.FromNumpy(mesh.points[t]), time)
            extent_attr.Set(Vt.Vec3fArray.FromNumpy(np.stack([lows[t], highs[t]])), time)

    primvars = UsdGeom.PrimvarsAPI(prim)
    if mesh.uv is not None:
        coords, face_uvs = mesh.uv
        st = primvars.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                    UsdGeom.Tokens.faceVarying)
        st.Set(Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(coords, dtype=np.float32)))
        st.SetIndices(Vt.IntArray.FromNumpy(np.ascontiguousarray(face_uvs.ravel(), dtype=np.int32)))
    if mesh.color is not None:
        interpolation = UsdGeom.Tokens.constant if len(mesh.color) == 1 else UsdGeom.Tokens.vertex
        color = primvars.CreatePrimvar("displayColor", Sdf.ValueTypeNames.Color3fArray, interpolation)
        color.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(mesh.color)))


def _extent(points: np.ndarray) -> np.ndarray:
    return np.stack([points.min(axis=0), points.max(axis=0)]).astype(np.float32)
