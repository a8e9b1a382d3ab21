#!/usr/bin/env python3
"""Nested usdz packages for tests/hostile_io.rs (issue 20, item 10), written and opened by
Pixar's USD library (usd-core), which is the oracle: every package here opens in it, and the
prims it composes are written to `expected.txt` next to them.

  implicit_root.usdz   root.usda references @inner.usdz@ with no member named: the inner
                       package's root layer (its first file, scene.usda) is implied, and its
                       default prim's child /World/Ball comes through.
  three_deep.usdz      a.usda sublayers @b.usdz@, whose root layer sublayers @c.usdz@, whose
                       root layer defines /Deep; every package's root layer is `root.usda` and
                       every path is relative to the layer that names it.

Run: /work/venv/bin/python tools/make_nested_usdz_fixtures.py
"""

import os
import tempfile

from pxr import Sdf, Usd

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "in", "hostile", "nested_usdz")


def write_text(path, text):
    with open(path, "w") as f:
        f.write(text)


def package(path, members):
    """A usdz of `members` ((name, file path), root layer first), as Sdf writes one."""
    if os.path.exists(path):
        os.remove(path)
    with Sdf.ZipFileWriter.CreateNew(path) as writer:
        for name, source in members:
            writer.AddFile(source, name)


def composed(path):
    stage = Usd.Stage.Open(path)
    assert stage, path
    return [f"{p.GetPath()}:{p.GetTypeName()}" for p in stage.Traverse()]


def main():
    os.makedirs(OUT, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        t = lambda name: os.path.join(tmp, name)
        # implicit_root.usdz
        write_text(t("scene.usda"), '#usda 1.0\n(\n    defaultPrim = "Thing"\n)\ndef Xform "Thing" {\n    def Sphere "Ball" {}\n}\n')
        package(t("inner.usdz"), [("scene.usda", t("scene.usda"))])
        write_text(t("root.usda"), '#usda 1.0\ndef Xform "World" (\n    references = @inner.usdz@\n) {}\n')
        package(os.path.join(OUT, "implicit_root.usdz"), [("root.usda", t("root.usda")), ("inner.usdz", t("inner.usdz"))])
        # three_deep.usdz
        write_text(t("c_root.usda"), '#usda 1.0\ndef Sphere "Deep" {}\n')
        package(t("c.usdz"), [("root.usda", t("c_root.usda"))])
        write_text(t("b_root.usda"), '#usda 1.0\n(\n    subLayers = [@./c.usdz@]\n)\ndef Xform "Middle" {}\n')
        package(t("b.usdz"), [("root.usda", t("b_root.usda")), ("c.usdz", t("c.usdz"))])
        write_text(t("a_root.usda"), '#usda 1.0\n(\n    subLayers = [@./b.usdz@]\n)\ndef Xform "Top" {}\n')
        package(os.path.join(OUT, "three_deep.usdz"), [("root.usda", t("a_root.usda")), ("b.usdz", t("b.usdz"))])
    with open(os.path.join(OUT, "expected.txt"), "w") as f:
        for name in ["implicit_root.usdz", "three_deep.usdz"]:
            f.write(f"{name}: {' '.join(composed(os.path.join(OUT, name)))}\n")


if __name__ == "__main__":
    main()
