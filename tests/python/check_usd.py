"""Opens a .usda written by `facesim export` with Pixar's USD (pip install usd-core) and checks
it: stage metadata (units, up axis, time codes), the mesh's topology, its texture coordinates
(`primvars:st`, face-varying and indexed, one index per triangle corner) and one time sample
of points and normals per frame, each with every vertex, and its parts (`GeomSubset`s of the
rig's material groups, a partition of the faces).

Usage: python3 check_usd.py FILE.usda FRAMES VERTICES TRIANGLES FPS   (prints "ok" or exits 1)
"""

import sys

from pxr import Usd, UsdGeom


def main(path, frames, vertices, triangles, fps):
    def need(cond, message):
        if not cond:
            sys.exit(f"usd check failed: {message}")

    stage = Usd.Stage.Open(path)
    need(stage is not None, "the stage did not open")
    need(UsdGeom.GetStageMetersPerUnit(stage) == 0.01, "metersPerUnit")
    need(UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y, "upAxis")
    need(stage.GetTimeCodesPerSecond() == fps, f"timeCodesPerSecond {stage.GetTimeCodesPerSecond()}")
    need(stage.GetStartTimeCode() == 0 and stage.GetEndTimeCode() == frames - 1, "time code range")
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/Surface"))
    need(mesh, "no Mesh at /Face/Surface")
    need(stage.GetDefaultPrim().GetPath() == "/Face", "default prim")
    counts = mesh.GetFaceVertexCountsAttr().Get()
    indices = mesh.GetFaceVertexIndicesAttr().Get()
    need(len(counts) == triangles and set(counts) == {3}, f"{len(counts)} faces")
    need(len(indices) == 3 * triangles and max(indices) == vertices - 1, "face vertex indices")
    need(mesh.GetNormalsInterpolation() == UsdGeom.Tokens.vertex, "normals interpolation")
    st = UsdGeom.PrimvarsAPI(mesh.GetPrim()).GetPrimvar("st")
    need(st and st.HasValue(), "no primvars:st")
    need(st.GetInterpolation() == UsdGeom.Tokens.faceVarying, f"st interpolation {st.GetInterpolation()}")
    need(str(st.GetTypeName()) == "texCoord2f[]", f"st type {st.GetTypeName()}")
    st_indices = st.GetIndices()
    need(st.IsIndexed() and len(st_indices) == 3 * triangles, f"{len(st_indices)} st indices")
    need(max(st_indices) == len(st.Get()) - 1, "st indices cover the coordinates")
    need(len(st.ComputeFlattened()) == 3 * triangles, "st flattens to one UV per corner")
    # The parts: one GeomSubset per material group, together a partition of the faces.
    subsets = UsdGeom.Subset.GetGeomSubsets(mesh, UsdGeom.Tokens.face, "materialBind")
    names = [s.GetPrim().GetName() for s in subsets]
    need("M_Face" in names and "M_Teeth" in names and "M_EyeLashes" in names, f"subsets {names}")
    valid, reason = UsdGeom.Subset.ValidateFamily(mesh, UsdGeom.Tokens.face, "materialBind")
    need(valid, f"materialBind subsets: {reason}")
    points, normals = mesh.GetPointsAttr(), mesh.GetNormalsAttr()
    samples = points.GetTimeSamples()
    need(samples == [float(k) for k in range(frames)], f"{len(samples)} point samples, expected {frames}")
    need(len(normals.GetTimeSamples()) == frames, "normal samples")
    need(len(mesh.GetExtentAttr().GetTimeSamples()) == frames, "extent samples")
    for t in samples:
        p, n = points.Get(t), normals.Get(t)
        need(len(p) == vertices and len(n) == vertices, f"sample {t}: {len(p)} points, {len(n)} normals")
    # The extent written with each frame bounds its points.
    last = points.Get(samples[-1])
    computed = UsdGeom.PointBased.ComputeExtent(last)
    stored = mesh.GetExtentAttr().Get(samples[-1])
    need(all(abs(a - b) <= 1e-4 for u, v in zip(computed, stored) for a, b in zip(u, v)), "extent")
    print("ok")


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), float(sys.argv[5]))
