#!/usr/bin/env python3
"""Writes strata's primvar fixtures with Pixar's USD library (pip install usd-core) into
tests/fixtures/usd/primvars/:

  interpolation.usda  one two-face mesh (a quad and a triangle, five points, subdivisionScheme
                      "none") per case: displayColor with each interpolation (constant, uniform,
                      vertex, varying, faceVarying), indexed and not, and primvars of other types
                      and names (float, float2/texCoord2f, double3, normal3f, int, color4f).
  interpolation.json  the oracle: for every case, the value usd-core's
                      UsdGeom.PrimvarsAPI(mesh).GetPrimvar(name).ComputeFlattened() gives each
                      face-vertex (constant: element 0; uniform: the face's; vertex and varying:
                      the point's; faceVarying: the face-vertex's).
  st0.usda            the preview fixture's quad and checker texture, its texture coordinates in
                      an indexed faceVarying primvar `st0` (no `st`), read by a
                      UsdPrimvarReader_float2 whose varname comes through an interface input.
  display.usda        unbound geometry under a uniform white dome: a two-face quad with uniform
                      displayColor, a Sphere with constant displayColor and a quad with constant
                      displayOpacity 0.25 (indexed) and no displayColor.
  checker.png         a copy of the preview fixtures' checker (32 x 32 RGB, 4 x 4 cells).

The camera looks down -z at the quad [-1, 1]^2 in the z = 0 plane from z = 5, with a 20 mm
aperture and a 50 mm focal length: the quad fills a square image exactly (as in the preview
fixtures).

Run it again whenever the fixtures must change; the Rust tests only read the written files.
"""
import json
import os
import shutil

from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, Vt

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "fixtures", "usd")
HERE = os.path.join(ROOT, "primvars")

# Two faces: a quad (0 1 2 3) and a triangle (1 4 2).
POINTS = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0), (2, 0, 0)]
COUNTS = [4, 3]
INDICES = [0, 1, 2, 3, 1, 4, 2]


def out(name):
    return os.path.join(HERE, name)


def stage_with_camera(name):
    stage = Usd.Stage.CreateNew(out(name))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.CreateFocalLengthAttr(50.0)
    cam.CreateHorizontalApertureAttr(20.0)
    cam.CreateVerticalApertureAttr(20.0)
    cam.AddTranslateOp().Set(Gf.Vec3d(0, 0, 5))
    UsdLux.DomeLight.Define(stage, "/World/Sky").CreateIntensityAttr(1.0)
    return stage


def counts_for(interpolation):
    return {
        "constant": 1,
        "uniform": len(COUNTS),
        "vertex": len(POINTS),
        "varying": len(POINTS),
        "faceVarying": len(INDICES),
    }[interpolation]


def element(k, width, scale=1.0):
    """A distinct, exactly representable value for element k."""
    return tuple(scale * (0.125 * (k + 1) + 0.0625 * c) for c in range(width))


CASES = []
for interp in ["constant", "uniform", "vertex", "varying", "faceVarying"]:
    for indexed in [False, True]:
        CASES.append(("displayColor", Sdf.ValueTypeNames.Color3fArray, 3, interp, indexed))
CASES += [
    ("roughness", Sdf.ValueTypeNames.FloatArray, 1, "vertex", True),
    ("st0", Sdf.ValueTypeNames.TexCoord2fArray, 2, "faceVarying", True),
    ("uv", Sdf.ValueTypeNames.Float2Array, 2, "vertex", False),
    ("offset", Sdf.ValueTypeNames.Double3Array, 3, "uniform", False),
    ("dir", Sdf.ValueTypeNames.Normal3fArray, 3, "faceVarying", False),
    ("id", Sdf.ValueTypeNames.IntArray, 1, "uniform", True),
    ("tint", Sdf.ValueTypeNames.Color4fArray, 4, "constant", False),
]


def make_value(type_name, width, values):
    if width == 1:
        if type_name == Sdf.ValueTypeNames.IntArray:
            return Vt.IntArray([int(v[0] * 16) for v in values])
        return [v[0] for v in values]
    vec = {2: Gf.Vec2f, 3: Gf.Vec3f, 4: Gf.Vec4f}[width]
    if type_name == Sdf.ValueTypeNames.Double3Array:
        vec = Gf.Vec3d
    return [vec(*v) for v in values]


def as_list(v):
    try:
        return [float(x) for x in v]
    except TypeError:
        return [float(v)]


def interpolation():
    stage = stage_with_camera("interpolation.usda")
    UsdGeom.Scope.Define(stage, "/World/Meshes")
    oracle = []
    for i, (name, type_name, width, interp, indexed) in enumerate(CASES):
        path = f"/World/Meshes/Case{i:02d}_{name}_{interp}{'_indexed' if indexed else ''}"
        mesh = UsdGeom.Mesh.Define(stage, path)
        mesh.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*p) for p in POINTS]))
        mesh.CreateFaceVertexCountsAttr(COUNTS)
        mesh.CreateFaceVertexIndicesAttr(INDICES)
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        n = counts_for(interp)
        primvar = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(name, type_name, interp)
        if indexed:
            # Fewer authored values than elements (one is shared), read in reverse order.
            authored = n - 1 if n > 2 else n
            values = [element(k, width) for k in range(authored)]
            indices = [(authored - 1 - k) % authored for k in range(n)]
            primvar.Set(make_value(type_name, width, values))
            primvar.SetIndices(Vt.IntArray(indices))
        else:
            primvar.Set(make_value(type_name, width, [element(k, width) for k in range(n)]))
        flat = [as_list(v) for v in primvar.ComputeFlattened()]
        assert primvar.GetInterpolation() == interp
        per_face_vertex = []
        fv = 0
        for face, count in enumerate(COUNTS):
            for _ in range(count):
                point = INDICES[fv]
                key = {"constant": 0, "uniform": face, "vertex": point, "varying": point, "faceVarying": fv}[interp]
                per_face_vertex.append(flat[key])
                fv += 1
        oracle.append({"mesh": path, "name": name, "interpolation": interp, "indexed": indexed,
                       "per_face_vertex": per_face_vertex})
    stage.GetRootLayer().Save()
    with open(out("interpolation.json"), "w") as f:
        f.write('{"counts": %s, "indices": %s, "cases": [\n' % (json.dumps(COUNTS), json.dumps(INDICES)))
        f.write(",\n".join(json.dumps(case) for case in oracle))
        f.write("\n]}\n")


def st0():
    stage = stage_with_camera("st0.usda")
    mesh = UsdGeom.Mesh.Define(stage, "/World/Quad")
    pts = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]
    mesh.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*p) for p in pts]))
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st0", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    # Authored out of order, put right by the indices.
    st.Set(Vt.Vec2fArray([Gf.Vec2f(1, 1), Gf.Vec2f(0, 0), Gf.Vec2f(0, 1), Gf.Vec2f(1, 0)]))
    st.SetIndices(Vt.IntArray([1, 3, 0, 2]))
    material = UsdShade.Material.Define(stage, "/Looks/Checker")
    pbr = UsdShade.Shader.Define(stage, "/Looks/Checker/PBR")
    pbr.CreateIdAttr("UsdPreviewSurface")
    material.CreateSurfaceOutput().ConnectToSource(pbr.CreateOutput("surface", Sdf.ValueTypeNames.Token))
    pbr.CreateInput("ior", Sdf.ValueTypeNames.Float).Set(1.0)
    varname = material.CreateInput("frame:stPrimvarName", Sdf.ValueTypeNames.Token)
    varname.Set("st0")
    reader = UsdShade.Shader.Define(stage, "/Looks/Checker/stReader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).ConnectToSource(varname)
    texture = UsdShade.Shader.Define(stage, "/Looks/Checker/Checker")
    texture.CreateIdAttr("UsdUVTexture")
    texture.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("checker.png")
    texture.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(
        reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    )
    texture.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
    pbr.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
        texture.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    )
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    stage.GetRootLayer().Save()


def display():
    stage = stage_with_camera("display.usda")
    # Left: a two-face quad (x in [-1, 0]) with uniform displayColor, faces at y < 0 and y > 0.
    left = UsdGeom.Mesh.Define(stage, "/World/Left")
    pts = [(-1, -1, 0), (0, -1, 0), (0, 0, 0), (-1, 0, 0), (0, 1, 0), (-1, 1, 0)]
    left.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*p) for p in pts]))
    left.CreateFaceVertexCountsAttr([4, 4])
    left.CreateFaceVertexIndicesAttr([0, 1, 2, 3, 3, 2, 4, 5])
    colour = UsdGeom.PrimvarsAPI(left).CreatePrimvar("displayColor", Sdf.ValueTypeNames.Color3fArray,
                                                    UsdGeom.Tokens.uniform)
    colour.Set(Vt.Vec3fArray([Gf.Vec3f(0.8, 0.3, 0.1), Gf.Vec3f(0.1, 0.6, 0.9)]))
    # Right bottom: a quad with constant displayOpacity 0.25, indexed, and no displayColor.
    glass = UsdGeom.Mesh.Define(stage, "/World/Faint")
    pts = [(0, -1, 0), (1, -1, 0), (1, 0, 0), (0, 0, 0)]
    glass.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*p) for p in pts]))
    glass.CreateFaceVertexCountsAttr([4])
    glass.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    opacity = UsdGeom.PrimvarsAPI(glass).CreatePrimvar("displayOpacity", Sdf.ValueTypeNames.FloatArray,
                                                      UsdGeom.Tokens.constant)
    opacity.Set([0.5, 0.25])
    opacity.SetIndices(Vt.IntArray([1]))
    # Right top: a sphere (analytic) with constant displayColor, radius 0.4 around (0.5, 0.5, -1).
    ball = UsdGeom.Sphere.Define(stage, "/World/Ball")
    ball.CreateRadiusAttr(0.4)
    ball.AddTranslateOp().Set(Gf.Vec3d(0.5, 0.5, -1))
    ball_colour = UsdGeom.PrimvarsAPI(ball).CreatePrimvar("displayColor", Sdf.ValueTypeNames.Color3fArray,
                                                         UsdGeom.Tokens.constant)
    ball_colour.Set(Vt.Vec3fArray([Gf.Vec3f(0.2, 0.7, 0.3)]))
    stage.GetRootLayer().Save()


def main():
    os.makedirs(HERE, exist_ok=True)
    shutil.copyfile(os.path.join(ROOT, "preview", "checker.png"), out("checker.png"))
    interpolation()
    st0()
    display()


if __name__ == "__main__":
    main()
