#!/usr/bin/env python3
"""Writes the instancing fixtures in tests/fixtures/instancing/ with Pixar's USD library
(`pip install usd-core`), so the files are laid out as USD writes them and the flattened
references are computed by USD itself, not by strata:

- asset.usda: an asset (a box mesh, a cube and a sphere under local transforms);
- instanced.usda / flattened.usda: four references to it, `instanceable = true` or not,
  under different transforms (one mirrored) and materials;
- pointinstancer.usda: a PointInstancer of two prototypes with positions, orientations
  (quath), scales, ids and invisibleIds;
- pointinstancer_flat.usda: the same instances as separate prims, each under the matrix
  that `UsdGeom.PointInstancer.ComputeInstanceTransformsAtTime` computes (prototype root
  transform included), with copies of the prototypes.

Run from the repository root: python3 tools/make_instancing_fixtures.py
"""
import math
import os

from pxr import Gf, Sdf, Usd, UsdGeom, Vt

OUT = os.path.join("tests", "fixtures", "instancing")


def box_mesh(stage, path):
    mesh = UsdGeom.Mesh.Define(stage, path)
    pts = [(-1, -1, -1), (1, -1, -1), (1, 1, -1), (-1, 1, -1), (-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1)]
    mesh.CreatePointsAttr([Gf.Vec3f(*p) for p in pts])
    mesh.CreateFaceVertexCountsAttr([4] * 6)
    mesh.CreateFaceVertexIndicesAttr([0, 3, 2, 1, 4, 5, 6, 7, 0, 1, 5, 4, 2, 3, 7, 6, 1, 2, 6, 5, 0, 4, 7, 3])
    # A polygonal box, not a subdivision surface (UsdGeom's default scheme).
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    return mesh


def common(stage):
    """Camera, lights, floor, materials."""
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    cam = UsdGeom.Camera.Define(stage, "/Camera")
    cam.CreateFocalLengthAttr(35)
    cam.CreateHorizontalApertureAttr(36)
    cam.CreateVerticalApertureAttr(27)
    xf = UsdGeom.Xformable(cam)
    xf.AddTranslateOp().Set(Gf.Vec3d(0, 3, 14))
    xf.AddRotateXYZOp().Set(Gf.Vec3f(-10, 0, 0))
    sky = stage.DefinePrim("/Sky", "DomeLight")
    sky.CreateAttribute("inputs:intensity", Sdf.ValueTypeNames.Float).Set(0.5)
    sun = stage.DefinePrim("/Sun", "DistantLight")
    sun.CreateAttribute("inputs:intensity", Sdf.ValueTypeNames.Float).Set(2.0)
    UsdGeom.Xformable(sun).AddRotateXYZOp().Set(Gf.Vec3f(-50, 30, 0))
    floor = UsdGeom.Mesh.Define(stage, "/Floor")
    floor.CreatePointsAttr([Gf.Vec3f(-20, -1, -20), Gf.Vec3f(-20, -1, 20), Gf.Vec3f(20, -1, 20), Gf.Vec3f(20, -1, -20)])
    floor.CreateFaceVertexCountsAttr([4])
    floor.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    floor.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    for name, albedo in [("Red", (0.8, 0.2, 0.1)), ("Blue", (0.1, 0.3, 0.8))]:
        mat = stage.DefinePrim(f"/Looks/{name}", "Material")
        sh = stage.DefinePrim(f"/Looks/{name}/Surface", "Shader")
        sh.CreateAttribute("info:implementationSource", Sdf.ValueTypeNames.Token, variability=Sdf.VariabilityUniform).Set("sourceAsset")
        sh.CreateAttribute("info:strata:sourceAsset", Sdf.ValueTypeNames.Asset, variability=Sdf.VariabilityUniform).Set("matte.ash")
        sh.CreateAttribute("info:strata:sourceAsset:subIdentifier", Sdf.ValueTypeNames.Token, variability=Sdf.VariabilityUniform).Set("matte")
        sh.CreateAttribute("inputs:albedo", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*albedo))


def bind(prim, material):
    prim.CreateRelationship("material:slotBinding:_000").SetTargets([Sdf.Path(material)])


def write_asset():
    stage = Usd.Stage.CreateNew(os.path.join(OUT, "asset.usda"))
    root = UsdGeom.Xform.Define(stage, "/Asset")
    stage.SetDefaultPrim(root.GetPrim())
    body = box_mesh(stage, "/Asset/Body")
    b = UsdGeom.Xformable(body)
    b.AddTranslateOp().Set(Gf.Vec3d(0, 0.2, 0))
    b.AddRotateYOp().Set(30)
    b.AddScaleOp().Set(Gf.Vec3f(0.6, 0.8, 0.5))
    cap = UsdGeom.Cube.Define(stage, "/Asset/Cap")
    cap.CreateSizeAttr(0.6)
    UsdGeom.Xformable(cap).AddTranslateOp().Set(Gf.Vec3d(0, 1.3, 0))
    bead = UsdGeom.Sphere.Define(stage, "/Asset/Bead")
    bead.CreateRadiusAttr(0.35)
    UsdGeom.Xformable(bead).AddTranslateOp().Set(Gf.Vec3d(0.9, -0.4, 0.3))
    stage.GetRootLayer().Save()


def write_instances(name, instanceable):
    stage = Usd.Stage.CreateNew(os.path.join(OUT, name))
    common(stage)
    placements = [
        ((-4.5, 0, 0), (0, 20, 0), (1, 1, 1), "/Looks/Red"),
        ((-1.5, 0, -1), (10, -35, 5), (1.2, 0.8, 1), "/Looks/Blue"),
        ((1.5, 0.2, 0.5), (0, 0, 15), (-1, 1, 1), "/Looks/Blue"),  # mirrored
        ((4.5, 0, 0), (0, 90, 0), (0.7, 0.7, 0.7), "/Looks/Red"),
    ]
    for i, (t, r, s, mat) in enumerate(placements):
        prim = stage.DefinePrim(f"/Things/Inst{i}", "Xform")
        prim.GetReferences().AddReference("asset.usda")
        prim.SetInstanceable(instanceable)
        xf = UsdGeom.Xformable(prim)
        xf.AddTranslateOp().Set(Gf.Vec3d(*t))
        xf.AddRotateXYZOp().Set(Gf.Vec3f(*r))
        xf.AddScaleOp().Set(Gf.Vec3f(*s))
        bind(prim, mat)
    stage.GetRootLayer().Save()


def point_instancer_stage(path):
    stage = Usd.Stage.CreateNew(os.path.join(OUT, path))
    common(stage)
    return stage


def write_point_instancer():
    stage = point_instancer_stage("pointinstancer.usda")
    pi = UsdGeom.PointInstancer.Define(stage, "/Field")
    bind(pi.GetPrim(), "/Looks/Blue")
    UsdGeom.Xformable(pi).AddTranslateOp().Set(Gf.Vec3d(0, 0.5, -1))
    box = box_mesh(stage, "/Field/Prototypes/Box")
    UsdGeom.Xformable(box).AddScaleOp().Set(Gf.Vec3f(0.5, 0.3, 0.4))
    ball = UsdGeom.Sphere.Define(stage, "/Field/Prototypes/Ball")
    ball.CreateRadiusAttr(0.5)
    # The prototype root's own transform applies under each instance's.
    UsdGeom.Xformable(ball).AddTranslateOp().Set(Gf.Vec3d(0, 0.3, 0))
    pi.CreatePrototypesRel().SetTargets([box.GetPath(), ball.GetPath()])
    n = 12
    positions, orientations, scales, indices, ids = [], [], [], [], []
    for k in range(n):
        a = k / n * 2 * math.pi
        positions.append(Gf.Vec3f(4.5 * math.cos(a), 0.4 * math.sin(3 * a), 3 * math.sin(a)))
        # An arbitrary rotation per instance: about a tilted axis.
        axis = Gf.Vec3d(math.sin(a), 1.0, 0.3 * math.cos(2 * a)).GetNormalized()
        rot = Gf.Rotation(axis, 37.0 * k)
        q = rot.GetQuat()
        orientations.append(Gf.Quath(q.GetReal(), Gf.Vec3h(q.GetImaginary())))
        scales.append(Gf.Vec3f(1 + 0.1 * k, 1 - 0.03 * k, 1 + 0.05 * (k % 3)))
        indices.append(k % 2)
        ids.append(100 + k)
    pi.CreatePositionsAttr(positions)
    pi.CreateOrientationsAttr(orientations)
    pi.CreateScalesAttr(scales)
    pi.CreateProtoIndicesAttr(indices)
    pi.CreateIdsAttr(Vt.Int64Array(ids))
    pi.CreateInvisibleIdsAttr(Vt.Int64Array([103, 108]))
    stage.GetRootLayer().Save()

    # The same instances as prims, under the matrices USD computes.
    xforms = pi.ComputeInstanceTransformsAtTime(
        Usd.TimeCode.Default(), Usd.TimeCode.Default(),
        UsdGeom.PointInstancer.IncludeProtoXform, UsdGeom.PointInstancer.IgnoreMask)
    assert len(xforms) == n
    world = UsdGeom.Xformable(pi).ComputeLocalToWorldTransform(Usd.TimeCode.Default())
    flat = point_instancer_stage("pointinstancer_flat.usda")
    group = UsdGeom.Xform.Define(flat, "/Field")
    bind(group.GetPrim(), "/Looks/Blue")
    invisible = {103, 108}
    src = stage.GetRootLayer()
    for k in range(n):
        if ids[k] in invisible:
            continue
        inst = UsdGeom.Xform.Define(flat, f"/Field/I{k}")
        UsdGeom.Xformable(inst).AddTransformOp().Set(Gf.Matrix4d(xforms[k]) * world)
        proto = ["Box", "Ball"][indices[k]]
        dst = f"/Field/I{k}/{proto}"
        Sdf.CopySpec(src, f"/Field/Prototypes/{proto}", flat.GetRootLayer(), dst)
        # The prototype's own transform is in the instance matrix already.
        p = flat.GetPrimAtPath(dst)
        for attr in list(p.GetAttributes()):
            if attr.GetName().startswith("xformOp"):
                p.RemoveProperty(attr.GetName())
    flat.GetRootLayer().Save()


def main():
    os.makedirs(OUT, exist_ok=True)
    write_asset()
    write_instances("instanced.usda", True)
    write_instances("flattened.usda", False)
    write_point_instancer()
    with open(os.path.join(OUT, "matte.ash"), "w") as f:
        f.write("substance matte {\n    input color albedo = color(0.5, 0.5, 0.5);\n"
                "    node d = diffuse(albedo: albedo);\n    surface = d.bsdf;\n}\n")


if __name__ == "__main__":
    main()
