#!/usr/bin/env python3
"""Writes the motion-blur fixtures in tests/fixtures/motion/ with Pixar's USD library
(`pip install usd-core`); every expected value is computed by USD itself, not by strata:

- xforms.usda: prims whose xformOps are sampled at a few frames — translate, rotateXYZ with
  a turn of more than 90 degrees between samples, orient (quatf, slerped), scale, a
  transform matrix, under an animated parent and past a `!resetXformStack!` — and a camera
  with `shutter:open` / `shutter:close`.
  xforms_expected.json: `ComputeLocalToWorldTransform(t)` of each at fractional times inside
  and outside the samples (row-major, row vectors, as USD writes matrices).

Run from the repository root: /work/venv/bin/python tools/make_motion_fixtures.py
"""
import json
import os

from pxr import Gf, Usd, UsdGeom

OUT = os.path.join("tests", "fixtures", "motion")
TIMES = [-0.5, 0.0, 0.1, 0.25, 0.37, 0.5, 0.75, 1.0, 1.3, 1.5, 1.99, 2.0, 2.6]


def main():
    os.makedirs(OUT, exist_ok=True)
    path = os.path.join(OUT, "xforms.usda")
    stage = Usd.Stage.CreateNew(path)
    stage.SetStartTimeCode(0)
    stage.SetEndTimeCode(2)
    parent = UsdGeom.Xform.Define(stage, "/Parent")
    op = parent.AddTranslateOp()
    op.Set(Gf.Vec3d(0, 0, 0), 0)
    op.Set(Gf.Vec3d(2, 1, 0), 2)
    spin = parent.AddRotateYOp()
    spin.Set(0.0, 0)
    spin.Set(170.0, 2)

    slide = UsdGeom.Xform.Define(stage, "/Parent/Slide")
    t = slide.AddTranslateOp()
    t.Set(Gf.Vec3d(-1, 0, 0), 0)
    t.Set(Gf.Vec3d(1, 0, 0), 1)
    t.Set(Gf.Vec3d(1, 3, 0), 2)
    r = slide.AddRotateXYZOp()
    r.Set(Gf.Vec3f(0, 0, 0), 0)
    r.Set(Gf.Vec3f(30, 120, -45), 1)
    s = slide.AddScaleOp()
    s.Set(Gf.Vec3f(1, 1, 1), 0)
    s.Set(Gf.Vec3f(2, 0.5, 1), 2)
    UsdGeom.Sphere.Define(stage, "/Parent/Slide/Ball")

    orient = UsdGeom.Xform.Define(stage, "/Parent/Orient")
    o = orient.AddOrientOp()
    o.Set(Gf.Quatf(1, 0, 0, 0), 0)
    o.Set(Gf.Quatf(0.0, 0.0, 1.0, 0.0), 1)  # half a turn about y: slerp's path matters
    o.Set(Gf.Quatf(0.5, 0.5, 0.5, 0.5), 2)
    pivot = orient.AddTranslateOp(opSuffix="pivot")
    pivot.Set(Gf.Vec3d(0, 0, 1))
    orient.AddTranslateOp(opSuffix="pivot", isInverseOp=True)
    UsdGeom.Cube.Define(stage, "/Parent/Orient/Box")

    matrix = UsdGeom.Xform.Define(stage, "/Matrix")
    m = matrix.AddTransformOp()
    m.Set(Gf.Matrix4d(1).SetTranslate(Gf.Vec3d(0, 0, 0)), 0)
    m.Set(Gf.Matrix4d(2).SetTranslate(Gf.Vec3d(4, 0, -2)), 2)

    reset = UsdGeom.Xform.Define(stage, "/Parent/Reset")
    reset.SetResetXformStack(True)
    rt = reset.AddTranslateOp()
    rt.Set(Gf.Vec3d(0, 5, 0), 0)
    rt.Set(Gf.Vec3d(0, 5, 4), 2)

    cam = UsdGeom.Camera.Define(stage, "/Cam")
    cam.CreateShutterOpenAttr(-0.25)
    cam.CreateShutterCloseAttr(0.25)
    cam.AddTranslateOp().Set(Gf.Vec3d(0, 0, 10))
    stage.GetRootLayer().Save()

    expected = {}
    for prim in ["/Parent", "/Parent/Slide", "/Parent/Slide/Ball", "/Parent/Orient/Box", "/Matrix", "/Parent/Reset"]:
        xf = UsdGeom.Xformable(stage.GetPrimAtPath(prim))
        expected[prim] = {
            repr(t): [x for row in xf.ComputeLocalToWorldTransform(Usd.TimeCode(t)) for x in row] for t in TIMES
        }
    cam = UsdGeom.Camera(stage.GetPrimAtPath("/Cam"))
    expected["shutter"] = [cam.GetShutterOpenAttr().Get(), cam.GetShutterCloseAttr().Get()]
    with open(os.path.join(OUT, "xforms_expected.json"), "w") as f:
        json.dump(expected, f, separators=(",", ":"))
        f.write("\n")


if __name__ == "__main__":
    main()
