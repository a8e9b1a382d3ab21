#!/usr/bin/env python3
"""Writes tests/fixtures/skel/arm_fractional_expected.json with Pixar's USD library
(`pip install usd-core`): the world-space skinned points of the meshes of arm.usda
(tools/make_skel_fixtures.py) that have no blend shapes, at fractional times between the
animation's samples, where deformation blur poses them (shutter keys are rarely whole frames).

The oracle is `UsdSkel.SkinningQuery.ComputeSkinnedPoints` with the skeleton's skinning
transforms at the time (`UsdSkel.SkeletonQuery.ComputeSkinningTransforms(t)`), placed by the
Skeleton's `ComputeLocalToWorldTransform(t)`. It is checked against `UsdSkel.BakeSkinning` at
whole times first, so it computes what arm_expected.json holds.

Run from the repository root: python3 tools/make_skel_fractional_expected.py
"""
import json
import os

from pxr import Gf, Usd, UsdGeom, UsdSkel, Vt

DIR = os.path.join("tests", "fixtures", "skel")
MESHES = ["/Arm/One", "/Arm/Four", "/Arm/Rigid"]
TIMES = [-2.75, 0.5, 3.3, 6.125, 12.75, 18.6]


def skinned_world_points(stage, cache, root, path, t):
    """The world-space skinned points of `path` at time `t`."""
    for binding in cache.ComputeSkelBindings(root, Usd.PrimDefaultPredicate):
        skel = binding.GetSkeleton()
        query = cache.GetSkelQuery(skel)
        for target in binding.GetSkinningTargets():
            if target.GetPrim().GetPath() != path:
                continue
            xforms = query.ComputeSkinningTransforms(t)
            points = UsdGeom.PointBased(target.GetPrim()).GetPointsAttr().Get(t)
            points = Vt.Vec3fArray([Gf.Vec3f(p) for p in points])
            assert target.ComputeSkinnedPoints(xforms, points, t), path
            to_world = UsdGeom.Xformable(skel.GetPrim()).ComputeLocalToWorldTransform(t)
            return [list(to_world.Transform(Gf.Vec3d(p))) for p in points]
    raise KeyError(path)


def main():
    stage = Usd.Stage.Open(os.path.join(DIR, "arm.usda"))
    root = UsdSkel.Root(stage.GetPrimAtPath("/Arm"))
    cache = UsdSkel.Cache()
    cache.Populate(root, Usd.PrimDefaultPredicate)
    with open(os.path.join(DIR, "arm_expected.json")) as f:
        baked = json.load(f)
    # The oracle agrees with the baked points at whole times.
    for mesh in baked["meshes"]:
        if mesh["prim"] not in MESHES:
            continue
        for t in baked["times"]:
            got = skinned_world_points(stage, cache, root, mesh["prim"], t)
            want = mesh["points"][str(t)]
            worst = max(max(abs(a - b) for a, b in zip(g, w)) for g, w in zip(got, want))
            assert worst < 1e-5, (mesh["prim"], t, worst)
    expected = {"times": TIMES, "meshes": []}
    for path in MESHES:
        entry = {"prim": path, "points": {}}
        for t in TIMES:
            entry["points"][str(t)] = skinned_world_points(stage, cache, root, path, t)
        expected["meshes"].append(entry)
    with open(os.path.join(DIR, "arm_fractional_expected.json"), "w") as f:
        json.dump(expected, f, indent=1)
        f.write("\n")


if __name__ == "__main__":
    main()
