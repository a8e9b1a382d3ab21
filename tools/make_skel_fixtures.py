#!/usr/bin/env python3
"""Writes the time-code and UsdSkel fixtures in tests/fixtures/skel/ with Pixar's USD library
(`pip install usd-core`); every expected value is computed by USD itself, not by strata:

- timesamples.usda (+ timesamples_sub.usda, timesamples_ref.usda): animated xformOps
  (translate, rotateXYZ, orient quatf, scale), points whose length changes, a light's
  intensity with a default, a camera's focal length, a material input, held int / token /
  bool samples, samples against a stronger default (and the reverse) across a sublayer, and a
  reference and a sublayer with layer offsets (offset and scale);
  timesamples_expected.json: `attr.Get(t)` at times before, between, on and after the
  samples and at the default time, plus `ComputeLocalToWorldTransform(t)` of the animated
  xforms.
- arm.usda: a SkelRoot with a three-joint arm Skeleton (bindTransforms, restTransforms, its
  own transform), a SkelAnimation that animates two of the joints in another order
  (translations, quatf rotations, half scales, a blend shape weight), and skinned meshes:
  weights of elementSize 1 (with a per-mesh `skel:joints` order), 2 (with a non-identity
  geomBindTransform, authored normals, and a sparse blend shape with an in-between) and 4,
  and a rigidly bound cube (constant interpolation). `skel:skeleton` is bound on the
  SkelRoot and inherited.
  arm_expected.json: the world-space points (and normals) of each mesh at integer times
  from `UsdSkel.BakeSkinning` on a copy of the stage, times the baked prim's
  `ComputeLocalToWorldTransform(t)`.
- moving.usda: a sphere moved by translate samples, for the `--time` CLI test.

Run from the repository root: python3 tools/make_skel_fixtures.py
"""
import json
import math
import os

from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, UsdSkel, Vt

OUT = os.path.join("tests", "fixtures", "skel")
TIMES = [-5.0, 0.0, 2.5, 5.0, 10.0, 12.5, 20.0, 25.0]


def flat(value):
    """A value as a flat list of numbers, or a string for tokens, strings and assets."""
    if value is None:
        return None
    if isinstance(value, (bool, int, float)):
        return [float(value)]
    if isinstance(value, str):
        return value
    if isinstance(value, Sdf.AssetPath):
        return value.path
    if isinstance(value, (Gf.Quatf, Gf.Quath, Gf.Quatd)):
        return [value.GetReal(), *value.GetImaginary()]
    if isinstance(value, (Gf.Matrix4d, Gf.Matrix3d)):
        return [x for row in value for x in row]
    try:
        items = list(value)
    except TypeError:
        return [float(value)]
    out = []
    for item in items:
        f = flat(item)
        out.extend(f if isinstance(f, list) else [f])
    return out


def matrix_list(m):
    return [m[r][c] for r in range(4) for c in range(4)]


# ---- time samples ----


def time_samples():
    sub = Usd.Stage.CreateNew(os.path.join(OUT, "timesamples_sub.usda"))
    p = sub.OverridePrim("/Comp")
    p.CreateAttribute("weakSamples", Sdf.ValueTypeNames.Float).Set(1.0, 0)
    p.CreateAttribute("weakSamples", Sdf.ValueTypeNames.Float).Set(2.0, 10)
    p.CreateAttribute("weakDefault", Sdf.ValueTypeNames.Float).Set(9.0)
    # Samples in the sublayer, retimed by the sublayer's offset and scale.
    p.CreateAttribute("subRetimed", Sdf.ValueTypeNames.Float).Set(0.0, 0)
    p.CreateAttribute("subRetimed", Sdf.ValueTypeNames.Float).Set(10.0, 10)
    sub.GetRootLayer().Save()

    ref = Usd.Stage.CreateNew(os.path.join(OUT, "timesamples_ref.usda"))
    a = ref.DefinePrim("/Asset", "Xform")
    ref.SetDefaultPrim(a)
    a.CreateAttribute("refRetimed", Sdf.ValueTypeNames.Float).Set(0.0, 0)
    a.CreateAttribute("refRetimed", Sdf.ValueTypeNames.Float).Set(10.0, 10)
    ref.GetRootLayer().Save()

    stage = Usd.Stage.CreateNew(os.path.join(OUT, "timesamples.usda"))
    stage.GetRootLayer().subLayerPaths.append("./timesamples_sub.usda")
    stage.SetStartTimeCode(0)
    stage.SetEndTimeCode(20)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)

    anim = UsdGeom.Xform.Define(stage, "/Anim")
    translate = anim.AddTranslateOp()
    translate.Set(Gf.Vec3d(5, 5, 5))
    translate.Set(Gf.Vec3d(0, 0, 0), 0)
    translate.Set(Gf.Vec3d(10, 2, 0), 10)
    rotate = anim.AddRotateXYZOp()
    rotate.Set(Gf.Vec3f(0, 0, 0), 0)
    rotate.Set(Gf.Vec3f(0, 90, 30), 10)
    orient = anim.AddOrientOp()
    orient.Set(Gf.Quatf(1, 0, 0, 0), 0)
    # 170° about x, written with a negative real part: the short arc goes the other way.
    half = math.radians(170) / 2
    orient.Set(Gf.Quatf(-math.cos(half), -math.sin(half), 0, 0), 20)
    scale = anim.AddScaleOp()
    scale.Set(Gf.Vec3f(1, 1, 1), 0)
    scale.Set(Gf.Vec3f(2, 0.5, 1), 20)

    child = UsdGeom.Xform.Define(stage, "/Anim/Child")
    m = child.AddTransformOp()
    m.Set(Gf.Matrix4d(1), 0)
    m.Set(Gf.Matrix4d().SetScale(Gf.Vec3d(2, 3, 4)) * Gf.Matrix4d().SetTranslate(Gf.Vec3d(1, 2, 3)), 10)

    ball = UsdGeom.Sphere.Define(stage, "/Anim/Ball")
    ball.CreateRadiusAttr().Set(1.0, 0)
    ball.GetRadiusAttr().Set(3.0, 10)

    mesh = UsdGeom.Mesh.Define(stage, "/Mesh")
    mesh.CreateFaceVertexCountsAttr([3])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2])
    pts = mesh.CreatePointsAttr()
    pts.Set([Gf.Vec3f(0, 0, 0), Gf.Vec3f(1, 0, 0), Gf.Vec3f(0, 1, 0)], 0)
    pts.Set([Gf.Vec3f(0, 0, 2), Gf.Vec3f(3, 0, 0), Gf.Vec3f(0, 1, 1)], 10)
    # Four points at 20: a length change, so 10..20 holds the sample at 10.
    pts.Set([Gf.Vec3f(0, 0, 0), Gf.Vec3f(1, 0, 0), Gf.Vec3f(0, 1, 0), Gf.Vec3f(1, 1, 0)], 20)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)

    light = UsdLux.SphereLight.Define(stage, "/Light")
    intensity = light.CreateIntensityAttr()
    intensity.Set(1.0)
    intensity.Set(2.0, 0)
    intensity.Set(4.0, 10)
    color = light.CreateColorAttr()
    color.Set(Gf.Vec3f(1, 0, 0), 0)
    color.Set(Gf.Vec3f(0, 0, 1), 20)

    cam = UsdGeom.Camera.Define(stage, "/Cam")
    cam.CreateFocalLengthAttr().Set(20.0, 0)
    cam.GetFocalLengthAttr().Set(80.0, 20)

    mat = UsdShade.Material.Define(stage, "/Looks/M")
    shader = UsdShade.Shader.Define(stage, "/Looks/M/Surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    base = shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f)
    base.Set(Gf.Vec3f(0.5, 0.5, 0.5))
    base.GetAttr().Set(Gf.Vec3f(1, 0, 0), 0)
    base.GetAttr().Set(Gf.Vec3f(0, 1, 0), 10)
    mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")

    comp = stage.DefinePrim("/Comp", "Xform")
    ints = comp.CreateAttribute("count", Sdf.ValueTypeNames.Int)
    ints.Set(1, 0)
    ints.Set(5, 10)
    tokens = comp.CreateAttribute("mode", Sdf.ValueTypeNames.Token)
    tokens.Set("a", 0)
    tokens.Set("b", 10)
    flags = comp.CreateAttribute("flag", Sdf.ValueTypeNames.Bool)
    flags.Set(False, 0)
    flags.Set(True, 10)
    doubles = comp.CreateAttribute("d", Sdf.ValueTypeNames.Double)
    doubles.Set(-1.0, -2)
    doubles.Set(1.0, 2)
    quats = comp.CreateAttribute("qs", Sdf.ValueTypeNames.QuathArray)
    quats.Set([Gf.Quath(1, 0, 0, 0), Gf.Quath(0, 0, 1, 0)], 0)
    quats.Set([Gf.Quath(0, 0, 1, 0), Gf.Quath(-0.6, 0, -0.8, 0)], 10)
    # A stronger default hides weaker samples; stronger samples beat a weaker default.
    comp.CreateAttribute("weakSamples", Sdf.ValueTypeNames.Float).Set(7.0)
    wd = comp.CreateAttribute("weakDefault", Sdf.ValueTypeNames.Float)
    wd.Set(3.0, 0)
    wd.Set(6.0, 10)
    comp.GetReferences().AddReference(Sdf.Reference("./timesamples_ref.usda", layerOffset=Sdf.LayerOffset(offset=5, scale=2)))
    stage.GetRootLayer().subLayerOffsets[0] = Sdf.LayerOffset(offset=-4, scale=0.5)
    stage.GetRootLayer().Save()

    stage = Usd.Stage.Open(os.path.join(OUT, "timesamples.usda"))
    attrs = [
        ("/Anim", "xformOp:translate"),
        ("/Anim", "xformOp:rotateXYZ"),
        ("/Anim", "xformOp:orient"),
        ("/Anim", "xformOp:scale"),
        ("/Anim/Child", "xformOp:transform"),
        ("/Anim/Ball", "radius"),
        ("/Mesh", "points"),
        ("/Light", "inputs:intensity"),
        ("/Light", "inputs:color"),
        ("/Cam", "focalLength"),
        ("/Looks/M/Surface", "inputs:diffuseColor"),
        ("/Comp", "count"),
        ("/Comp", "mode"),
        ("/Comp", "flag"),
        ("/Comp", "d"),
        ("/Comp", "qs"),
        ("/Comp", "weakSamples"),
        ("/Comp", "weakDefault"),
        ("/Comp", "refRetimed"),
        ("/Comp", "subRetimed"),
    ]
    expected = {"start": stage.GetStartTimeCode(), "attributes": [], "world": []}
    for path, name in attrs:
        attr = stage.GetPrimAtPath(path).GetAttribute(name)
        def authored(t):
            # A schema's fallback (a Sphere's radius 1) is no authored value: strata's readers
            # apply their own defaults, so the stage has none.
            fallback = attr.GetResolveInfo(t).GetSource() == Usd.ResolveInfoSourceFallback
            return None if fallback else flat(attr.Get(t))

        values = {"default": authored(Usd.TimeCode.Default())}
        for t in TIMES:
            values[repr(t)] = authored(t)
        expected["attributes"].append({"prim": path, "attribute": name, "values": values})
    for path in ["/Anim", "/Anim/Child"]:
        xf = UsdGeom.Xformable(stage.GetPrimAtPath(path))
        mats = {repr(t): matrix_list(xf.ComputeLocalToWorldTransform(t)) for t in TIMES}
        expected["world"].append({"prim": path, "matrices": mats})
    with open(os.path.join(OUT, "timesamples_expected.json"), "w") as f:
        json.dump(expected, f, indent=1)
        f.write("\n")


# ---- UsdSkel ----

JOINTS = ["Shoulder", "Shoulder/Elbow", "Shoulder/Elbow/Wrist"]


def translation(x, y, z):
    return Gf.Matrix4d().SetTranslate(Gf.Vec3d(x, y, z))


def quat_about(axis, degrees):
    r = Gf.Rotation(Gf.Vec3d(*axis), degrees).GetQuat()
    return Gf.Quatf(r.GetReal(), Gf.Vec3f(r.GetImaginary()))


def strip(stage, path, length=6, rows=2):
    """A strip of quads along x from 0 to `length`, `rows` points across y."""
    mesh = UsdGeom.Mesh.Define(stage, path)
    pts = []
    for i in range(length + 1):
        for j in range(rows):
            pts.append(Gf.Vec3f(i, j - 0.5 * (rows - 1), 0.1 * i * j))
    counts, indices = [], []
    for i in range(length):
        for j in range(rows - 1):
            a = i * rows + j
            counts.append(4)
            indices.extend([a, a + rows, a + rows + 1, a + 1])
    mesh.CreatePointsAttr(pts)
    mesh.CreateFaceVertexCountsAttr(counts)
    mesh.CreateFaceVertexIndicesAttr(indices)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    return mesh, pts


def weights_along(x, element_size):
    """Joint indices and weights (skeleton order) of a point at `x` along the arm."""
    # Each joint's influence falls off linearly from its position (0, 2, 4).
    raw = [max(0.0, 1.0 - abs(x - 2.0 * j) / 2.5) for j in range(3)]
    order = sorted(range(3), key=lambda j: -raw[j])[:element_size]
    total = sum(raw[j] for j in order) or 1.0
    idx = list(order) + [0] * (element_size - len(order))
    w = [raw[j] / total for j in order] + [0.0] * (element_size - len(order))
    return idx, w


def arm():
    stage = Usd.Stage.CreateNew(os.path.join(OUT, "arm.usda"))
    stage.SetStartTimeCode(0)
    stage.SetEndTimeCode(20)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)

    root = UsdSkel.Root.Define(stage, "/Arm")
    root.AddTranslateOp().Set(Gf.Vec3d(1, 0, 0))
    UsdSkel.BindingAPI.Apply(root.GetPrim()).CreateSkeletonRel().SetTargets(["/Arm/Skel"])

    skel = UsdSkel.Skeleton.Define(stage, "/Arm/Skel")
    skel.AddTranslateOp().Set(Gf.Vec3d(0, 1, 0))
    skel.AddRotateXOp().Set(15.0)
    skel.CreateJointsAttr(JOINTS)
    skel.CreateBindTransformsAttr(Vt.Matrix4dArray([translation(0, 0, 0), translation(2, 0, 0), translation(4, 0, 0)]))
    skel.CreateRestTransformsAttr(Vt.Matrix4dArray([translation(0, 0, 0), translation(2, 0, 0), translation(2, 0.2, 0)]))
    UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets(["/Arm/Anim"])

    anim = UsdSkel.Animation.Define(stage, "/Arm/Anim")
    # Two of the three joints, in another order: the wrist keeps its rest transform.
    anim.CreateJointsAttr(["Shoulder/Elbow", "Shoulder"])
    tr = anim.CreateTranslationsAttr()
    tr.Set(Vt.Vec3fArray([Gf.Vec3f(2, 0, 0), Gf.Vec3f(0, 0, 0)]), 0)
    tr.Set(Vt.Vec3fArray([Gf.Vec3f(2, 0.5, 0), Gf.Vec3f(0, 0, 0.5)]), 10)
    tr.Set(Vt.Vec3fArray([Gf.Vec3f(1.5, 0, 0), Gf.Vec3f(0, 0, 0)]), 20)
    rot = anim.CreateRotationsAttr()
    rot.Set(Vt.QuatfArray([quat_about((0, 0, 1), 0), quat_about((0, 0, 1), 0)]), 0)
    rot.Set(Vt.QuatfArray([quat_about((0, 1, 0), 60), quat_about((0, 0, 1), 30)]), 10)
    rot.Set(Vt.QuatfArray([quat_about((1, 1, 0), 120), quat_about((0, 0, 1), -45)]), 20)
    sc = anim.CreateScalesAttr()
    sc.Set(Vt.Vec3hArray([Gf.Vec3h(1, 1, 1), Gf.Vec3h(1, 1, 1)]), 0)
    sc.Set(Vt.Vec3hArray([Gf.Vec3h(1, 1.5, 1), Gf.Vec3h(1.25, 1, 1)]), 10)
    anim.CreateBlendShapesAttr(["bulge"])
    bw = anim.CreateBlendShapeWeightsAttr()
    bw.Set(Vt.FloatArray([0.0]), 0)
    bw.Set(Vt.FloatArray([0.8]), 10)
    bw.Set(Vt.FloatArray([1.5]), 20)

    # elementSize 2, geomBindTransform, normals, blend shape with an in-between.
    two, pts = strip(stage, "/Arm/Two")
    two.AddTranslateOp().Set(Gf.Vec3d(0, 0, 1))
    normals = [Gf.Vec3f(0, 0.2 * (i % 2), 1).GetNormalized() for i in range(len(pts))]
    two.CreateNormalsAttr(normals)
    two.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    b = UsdSkel.BindingAPI.Apply(two.GetPrim())
    idx, w = [], []
    for p in pts:
        i, ww = weights_along(p[0], 2)
        idx += i
        w += ww
    b.CreateJointIndicesPrimvar(False, 2).Set(idx)
    b.CreateJointWeightsPrimvar(False, 2).Set(w)
    bind = Gf.Matrix4d().SetRotate(Gf.Rotation(Gf.Vec3d(0, 1, 0), 10)) * translation(0.1, 0, 1)
    b.CreateGeomBindTransformAttr(bind)
    bulge = UsdSkel.BlendShape.Define(stage, "/Arm/Two/Bulge")
    bulge.CreatePointIndicesAttr([3, 4, 10])
    bulge.CreateOffsetsAttr([Gf.Vec3f(0, 0, 1), Gf.Vec3f(0, 0.5, 0.5), Gf.Vec3f(0.2, 0, -1)])
    inb = bulge.CreateInbetween("half")
    inb.SetWeight(0.5)
    inb.SetOffsets([Gf.Vec3f(0, 0, 0.8), Gf.Vec3f(0, 0.1, 0), Gf.Vec3f(0, 0, 0)])
    b.CreateBlendShapesAttr(["bulge"])
    b.CreateBlendShapeTargetsRel().SetTargets([bulge.GetPath()])

    # elementSize 1 with a per-mesh joint order.
    one, pts = strip(stage, "/Arm/One")
    one.AddTranslateOp().Set(Gf.Vec3d(0, 0, -1))
    mesh_joints = ["Shoulder/Elbow/Wrist", "Shoulder", "Shoulder/Elbow"]
    b = UsdSkel.BindingAPI.Apply(one.GetPrim())
    b.CreateJointsAttr(mesh_joints)
    idx = []
    for p in pts:
        i, _ = weights_along(p[0], 1)
        idx.append(mesh_joints.index(JOINTS[i[0]]))
    b.CreateJointIndicesPrimvar(False, 1).Set(idx)
    b.CreateJointWeightsPrimvar(False, 1).Set([1.0] * len(pts))
    b.CreateGeomBindTransformAttr(translation(0, 0, -1))

    # elementSize 4 (one unused influence), three rows of points.
    four, pts = strip(stage, "/Arm/Four", rows=3)
    b = UsdSkel.BindingAPI.Apply(four.GetPrim())
    idx, w = [], []
    for p in pts:
        i, ww = weights_along(p[0], 4)
        idx += i
        w += ww
    b.CreateJointIndicesPrimvar(False, 4).Set(idx)
    b.CreateJointWeightsPrimvar(False, 4).Set(w)

    # A rigid binding: constant interpolation, the same influences for every point.
    cube = UsdGeom.Mesh.Define(stage, "/Arm/Rigid")
    s = 0.3
    cube.CreatePointsAttr([Gf.Vec3f(x * s + 3, y * s, z * s) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    cube.CreateFaceVertexCountsAttr([4] * 6)
    cube.CreateFaceVertexIndicesAttr([0, 1, 3, 2, 4, 6, 7, 5, 0, 4, 5, 1, 2, 3, 7, 6, 0, 2, 6, 4, 1, 5, 7, 3])
    cube.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    b = UsdSkel.BindingAPI.Apply(cube.GetPrim())
    b.CreateJointIndicesPrimvar(True, 2).Set([1, 2])
    b.CreateJointWeightsPrimvar(True, 2).Set([0.7, 0.3])

    stage.GetRootLayer().Save()

    # The oracle: bake on an in-memory copy, read the baked points at each integer time.
    baked = Usd.Stage.Open(stage.GetRootLayer().identifier)
    baked.SetEditTarget(baked.GetSessionLayer())
    times = [-5, 0, 3, 5, 7, 10, 13, 17, 20, 25]
    assert UsdSkel.BakeSkinning(UsdSkel.Root(baked.GetPrimAtPath("/Arm")), Gf.Interval(min(times), max(times)))
    expected = {"times": times, "meshes": []}
    for path in ["/Arm/Two", "/Arm/One", "/Arm/Four", "/Arm/Rigid"]:
        mesh = UsdGeom.Mesh(baked.GetPrimAtPath(path))
        entry = {"prim": path, "points": {}, "normals": {}}
        for t in times:
            l2w = mesh.ComputeLocalToWorldTransform(t)
            entry["points"][str(t)] = [list(l2w.Transform(Gf.Vec3d(p))) for p in mesh.GetPointsAttr().Get(t)]
            normals = mesh.GetNormalsAttr().Get(t)
            if normals:
                n2w = l2w.ExtractRotationMatrix().GetInverse().GetTranspose()
                entry["normals"][str(t)] = [list((Gf.Vec3d(n) * n2w).GetNormalized()) for n in normals]
        expected["meshes"].append(entry)
    with open(os.path.join(OUT, "arm_expected.json"), "w") as f:
        json.dump(expected, f, indent=1)
        f.write("\n")


def moving():
    stage = Usd.Stage.CreateNew(os.path.join(OUT, "moving.usda"))
    stage.SetStartTimeCode(0)
    stage.SetEndTimeCode(10)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    cam = UsdGeom.Camera.Define(stage, "/Cam")
    cam.CreateFocalLengthAttr(35)
    UsdGeom.Xformable(cam).AddTranslateOp().Set(Gf.Vec3d(0, 0, 10))
    sun = UsdLux.DistantLight.Define(stage, "/Sun")
    sun.CreateIntensityAttr(3.0)
    ball = UsdGeom.Sphere.Define(stage, "/Ball")
    op = ball.AddTranslateOp()
    op.Set(Gf.Vec3d(-2.5, 0, 0), 0)
    op.Set(Gf.Vec3d(2.5, 0, 0), 10)
    stage.GetRootLayer().Save()


if __name__ == "__main__":
    os.makedirs(OUT, exist_ok=True)
    time_samples()
    arm()
    moving()
