#!/usr/bin/env python3
"""Writes strata's binary-USD fixtures with Pixar's own USD library.

    pip install usd-core          # Pixar's USD for Python (no build needed)
    python3 tools/make_usd_fixtures.py

Everything goes to tests/fixtures/usd/binary/. Every layer is authored once, in memory,
and exported by USD twice, as text (.usda) and as a binary crate (.usdc): the twins hold
the same scene description, so strata must compose them to identical stages
(tests/usd_binary.rs). The files are committed; the Rust tests never need Python.

  kitchen.usda / kitchen.usdc  a mesh with slot bindings (`material:slotBinding:_000`, an
                               override `_000:_:_010`, an empty binding), materials with
                               strata source-asset shaders and `.connect`ed interface inputs,
                               and every value type strata reads (point3f[], color3f, token,
                               asset, matrix4d, quatf[], int[], texCoord2f[], dictionaries,
                               a blocked value, time samples), variants, inherits, an
                               internal reference
  kitchen_binary.usd           the same layer as a crate under the format-neutral `.usd`
  sub / asset / payload .usd[ac]  a sublayer, a referenced asset and a payload, each twice
  root.usda                    sublayers sub.usdc, references asset.usdc, payloads payload.usdc
  root_twin.usda               the same arcs to the .usda twins
  package.usdz                 a usdz: scene.usdc (first, the root layer), its sublayer
                               lights.usda, textured.ash,
                               tex/checker.exr (read by strata's texture node) and
                               tex/checker.png (for UsdPreviewSurface readers)
  package/                     the same files unpacked, with scene.usda for scene.usdc

Run it again whenever the fixtures must change.
"""
import os
import shutil
import struct
import zlib

from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, Vt

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OUT = os.path.join(ROOT, "tests", "fixtures", "usd", "binary")


def out(*names):
    return os.path.join(OUT, *names)


def export_twins(layer, stem, directory=OUT):
    """Writes `layer` as stem.usda (text) and stem.usdc (crate)."""
    layer.Export(os.path.join(directory, stem + ".usda"), args={"format": "usda"})
    layer.Export(os.path.join(directory, stem + ".usdc"), args={"format": "usdc"})


def new_stage():
    layer = Sdf.Layer.CreateAnonymous(".usda")
    return Usd.Stage.Open(layer), layer


def material(stage, path, substance, inputs=None, asset="textured.ash"):
    """A Material with a strata source-asset shader (docs/DESIGN.md, Inputs 2)."""
    mat = UsdShade.Material.Define(stage, path)
    shader = UsdShade.Shader.Define(stage, path + "/Surface")
    shader.SetSourceAsset(Sdf.AssetPath(asset), "strata")
    shader.SetSourceAssetSubIdentifier(substance, "strata")
    for name, (type_name, value) in (inputs or {}).items():
        shader.CreateInput(name, type_name).Set(value)
    return mat, shader


def bind(prim, slot_rel, target):
    """A slot binding (docs/DESIGN.md, Inputs 3): `rel material:slotBinding:_000 = </X>`."""
    rel = prim.CreateRelationship(slot_rel, custom=False)
    if target is None:
        rel.SetTargets([])  # an authored empty binding: removes the slot
    else:
        rel.SetTargets([Sdf.Path(target)])
    return rel


def kitchen():
    stage, layer = new_stage()
    layer.customLayerData = {"generator": "tools/make_usd_fixtures.py", "version": 2}
    layer.documentation = "binary USD fixture: every value type strata reads"
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)

    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    Usd.ModelAPI(world).SetKind("assembly")
    world.AddTransformOp().Set(Gf.Matrix4d(1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0.5, -0.25, 2, 1))
    bind(world.GetPrim(), "material:slotBinding:_000", "/Looks/Clay")
    bind(world.GetPrim(), "material:slotBinding:_050", "/Looks/Dirt")

    mesh = UsdGeom.Mesh.Define(stage, "/World/Quad")
    mesh.CreatePointsAttr([(-1, 0, -1), (1, 0, -1), (1, 0, 1), (-1, 0, 1)])
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    mesh.CreateNormalsAttr([(0, 1, 0)] * 4)
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
        "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying
    )
    st.Set([(0, 0), (1, 0), (1, 1), (0, 1)])
    mesh.CreateDisplayColorAttr([(0.1, 0.2, 0.3)])
    mesh.CreateDoubleSidedAttr(True)
    quad = mesh.GetPrim()
    bind(quad, "material:slotBinding:_000", "/Looks/Red")
    bind(quad, "material:slotBinding:_000:_:_010", "/Looks/RedPaint")
    bind(quad, "material:slotBinding:_050", None)
    quad.CreateRelationship("material:slotBinding:_070")  # declared only: no binding

    ball = UsdGeom.Sphere.Define(stage, "/World/Ball")
    ball.CreateRadiusAttr(0.75)
    ball.AddTranslateOp().Set(Gf.Vec3d(0, 1, 0))
    ball.AddOrientOp().Set(Gf.Quatf(0.70710677, 0, 0.70710677, 0))
    ball.GetPrim().GetInherits().AddInherit("/_Shared")

    values = stage.DefinePrim("/World/Values", "Scope")
    values.SetCustomDataByKey("note", "custom data")
    values.SetCustomDataByKey("nested", {"count": 3, "scale": 0.5, "name": Vt.Token("tok")})
    attrs = [
        ("aColor", Sdf.ValueTypeNames.Color3f, Gf.Vec3f(0.8, 0.1, 0.05)),
        ("aToken", Sdf.ValueTypeNames.Token, "faceVarying"),
        ("aAsset", Sdf.ValueTypeNames.Asset, Sdf.AssetPath("tex/checker.exr")),
        ("aAssets", Sdf.ValueTypeNames.AssetArray, [Sdf.AssetPath("a.exr"), Sdf.AssetPath("../b.exr")]),
        ("aMatrix", Sdf.ValueTypeNames.Matrix4d, Gf.Matrix4d(2, 0, 0, 0, 0, 3, 0, 0, 0, 0, 4, 0, 1, 2, 3, 1)),
        ("aMatrices", Sdf.ValueTypeNames.Matrix4dArray, [Gf.Matrix4d(1), Gf.Matrix4d(0.5)]),
        ("aQuats", Sdf.ValueTypeNames.QuatfArray, [Gf.Quatf(1, 0, 0, 0), Gf.Quatf(0.5, 0.5, 0.5, 0.5)]),
        ("aQuatd", Sdf.ValueTypeNames.Quatd, Gf.Quatd(0.25, 0.5, 0.75, 1)),
        ("aInts", Sdf.ValueTypeNames.IntArray, [1, -2, 3, 2147483647]),
        ("aInt64", Sdf.ValueTypeNames.Int64, -9007199254740993),
        ("aUchar", Sdf.ValueTypeNames.UChar, 200),
        ("aUint", Sdf.ValueTypeNames.UInt, 4000000000),
        ("aBool", Sdf.ValueTypeNames.Bool, True),
        ("aBools", Sdf.ValueTypeNames.BoolArray, [True, False, True]),
        ("aFloat", Sdf.ValueTypeNames.Float, 0.1),
        ("aFloats", Sdf.ValueTypeNames.FloatArray, [0.1, 1.0 / 3.0, -2.5e-7, 1e30]),
        ("aDouble", Sdf.ValueTypeNames.Double, 0.1),
        ("aDoubles", Sdf.ValueTypeNames.DoubleArray, [1.0 / 3.0, 2e-300]),
        ("aString", Sdf.ValueTypeNames.String, 'quote " and\nnewline'),
        ("aStrings", Sdf.ValueTypeNames.StringArray, ["x", "y"]),
        ("aTokens", Sdf.ValueTypeNames.TokenArray, ["a", "b", "c"]),
        ("aTexCoords", Sdf.ValueTypeNames.TexCoord2fArray, [(0, 0.5), (0.25, 1)]),
        ("aNormals", Sdf.ValueTypeNames.Normal3fArray, [(0, 0, 1)]),
        ("aInt3", Sdf.ValueTypeNames.Int3, Gf.Vec3i(1, 2, 3)),
        ("aDouble3", Sdf.ValueTypeNames.Double3, Gf.Vec3d(0.1, 0.2, 0.3)),
        ("aFloat4", Sdf.ValueTypeNames.Float4, Gf.Vec4f(1, 2, 3, 4)),
        ("aTimecode", Sdf.ValueTypeNames.TimeCode, Sdf.TimeCode(24)),
        ("aEmpty", Sdf.ValueTypeNames.Point3fArray, []),
    ]
    for name, type_name, value in attrs:
        values.CreateAttribute(name, type_name).Set(value)
    values.GetAttribute("aColor").SetDocumentation("a colour")
    uniform = values.CreateAttribute("aUniform", Sdf.ValueTypeNames.Token, custom=True, variability=Sdf.VariabilityUniform)
    uniform.Set("u")
    uniform.SetMetadata("allowedTokens", ["u", "v"])
    blocked = values.CreateAttribute("aBlocked", Sdf.ValueTypeNames.Float)
    blocked.Block()
    animated = values.CreateAttribute("aAnimated", Sdf.ValueTypeNames.Double)
    animated.Set(1.5, 1)
    animated.Set(2.5, 2)

    variants = stage.DefinePrim("/World/Variants", "Xform")
    vset = variants.GetVariantSets().AddVariantSet("look")
    for name, radius in (("small", 0.25), ("large", 2.0)):
        vset.AddVariant(name)
        vset.SetVariantSelection(name)
        with vset.GetVariantEditContext():
            s = UsdGeom.Sphere.Define(stage, "/World/Variants/Shape")
            s.CreateRadiusAttr(radius)
            bind(s.GetPrim(), "material:slotBinding:_000", "/Looks/Red" if name == "large" else "/Looks/Clay")
    vset.SetVariantSelection("large")

    internal = stage.DefinePrim("/World/Internal")
    internal.GetReferences().AddInternalReference("/_Shared")

    shared = stage.CreateClassPrim("/_Shared")
    shared.CreateAttribute("sharedValue", Sdf.ValueTypeNames.Float).Set(7.0)
    bind(shared, "material:slotBinding:_020", "/Looks/Dirt")

    looks = UsdGeom.Scope.Define(stage, "/Looks")
    material(stage, "/Looks/Clay", "clay", {"albedo": (Sdf.ValueTypeNames.Color3f, Gf.Vec3f(0.5, 0.5, 0.5))})
    red, red_shader = material(stage, "/Looks/Red", "clay")
    iface = red.CreateInput("albedo", Sdf.ValueTypeNames.Color3f)
    iface.Set(Gf.Vec3f(0.8, 0.05, 0.05))
    red_shader.CreateInput("albedo", Sdf.ValueTypeNames.Color3f).ConnectToSource(iface)
    material(stage, "/Looks/RedPaint", "paint")
    material(stage, "/Looks/Dirt", "dirt", {"coverage": (Sdf.ValueTypeNames.Float, 0.4)})
    del looks
    return layer


def arcs():
    """sub, asset and payload twins, and the two roots that compose them."""
    for stem, build in (("sub", "sub"), ("asset", "asset"), ("payload", "payload")):
        stage, layer = new_stage()
        if build == "sub":
            over = stage.OverridePrim("/World")
            over.CreateAttribute("fromSub", Sdf.ValueTypeNames.Int).Set(1)
            bind(over, "material:slotBinding:_000", "/World/Looks/SubLook")
            UsdShade.Material.Define(stage, "/World/Looks/SubLook")
        elif build == "asset":
            asset = UsdGeom.Xform.Define(stage, "/Asset")
            stage.SetDefaultPrim(asset.GetPrim())
            m = UsdGeom.Mesh.Define(stage, "/Asset/Body")
            m.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
            m.CreateFaceVertexCountsAttr([3])
            m.CreateFaceVertexIndicesAttr([0, 1, 2])
            bind(m.GetPrim(), "material:slotBinding:_010", "/Asset/Look")
            UsdShade.Material.Define(stage, "/Asset/Look")
        else:
            p = UsdGeom.Xform.Define(stage, "/Heavy")
            stage.SetDefaultPrim(p.GetPrim())
            c = UsdGeom.Cube.Define(stage, "/Heavy/Box")
            c.CreateSizeAttr(0.5)
        export_twins(layer, stem)

    for name, ext in (("root.usda", ".usdc"), ("root_twin.usda", ".usda")):
        layer = Sdf.Layer.CreateAnonymous(".usda")
        layer.subLayerPaths.append("sub" + ext)
        stage = Usd.Stage.Open(layer)
        world = UsdGeom.Xform.Define(stage, "/World")
        stage.SetDefaultPrim(world.GetPrim())
        ref = stage.DefinePrim("/World/Ref")
        ref.GetReferences().AddReference("asset" + ext)
        heavy = stage.DefinePrim("/World/Heavy")
        heavy.GetPayloads().AddPayload("payload" + ext)
        layer.Export(out(name), args={"format": "usda"})


def png_bytes(width, height, pixel):
    """A minimal 8-bit RGB PNG."""
    raw = b"".join(b"\x00" + b"".join(bytes(pixel(x, y)) for x in range(width)) for y in range(height))

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")


def exr_bytes(width, height, pixel):
    """A minimal uncompressed scanline RGB float EXR (channels B, G, R, as EXR sorts them)."""

    def attr(name, kind, data):
        return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(data)) + data

    channels = b"".join(c + b"\0" + struct.pack("<iB3xii", 2, 0, 1, 1) for c in (b"B", b"G", b"R")) + b"\0"
    box = struct.pack("<iiii", 0, 0, width - 1, height - 1)
    header = (
        b"\x76\x2f\x31\x01" + struct.pack("<i", 2)
        + attr("channels", "chlist", channels)
        + attr("compression", "compression", b"\0")
        + attr("dataWindow", "box2i", box)
        + attr("displayWindow", "box2i", box)
        + attr("lineOrder", "lineOrder", b"\0")
        + attr("pixelAspectRatio", "float", struct.pack("<f", 1.0))
        + attr("screenWindowCenter", "v2f", struct.pack("<ff", 0, 0))
        + attr("screenWindowWidth", "float", struct.pack("<f", 1.0))
        + b"\0"
    )
    line_size = 8 + width * 3 * 4
    table_end = len(header) + 8 * height
    offsets = b"".join(struct.pack("<Q", table_end + y * line_size) for y in range(height))
    lines = b""
    for y in range(height):
        px = [pixel(x, y) for x in range(width)]
        data = b"".join(struct.pack("<f", p[c]) for c in (2, 1, 0) for p in px)
        lines += struct.pack("<ii", y, len(data)) + data
    return header + offsets + lines


TEXTURED_ASH = """// A diffuse surface coloured by a texture the scene names (tools/make_usd_fixtures.py).
substance textured {
    input string file = "";
    node tx = texture(file: file);
    node d = diffuse(albedo: tx.out);
    surface = d.bsdf;
}

substance matte {
    input color albedo = color(0.5, 0.5, 0.5);
    node d = diffuse(albedo: albedo);
    surface = d.bsdf;
}

substance clay {
    input color albedo = color(0.5, 0.5, 0.5);
    node d = diffuse(albedo: albedo);
    surface = d.bsdf;
}
"""


def package():
    """package.usdz and its unpacked twin package/."""
    unpacked = out("package")
    if os.path.isdir(unpacked):
        shutil.rmtree(unpacked)
    os.makedirs(os.path.join(unpacked, "tex"))

    def checker(x, y):
        return (0.9, 0.6, 0.1) if (x // 2 + y // 2) % 2 == 0 else (0.05, 0.2, 0.6)

    with open(os.path.join(unpacked, "tex", "checker.exr"), "wb") as f:
        f.write(exr_bytes(8, 8, checker))
    with open(os.path.join(unpacked, "tex", "checker.png"), "wb") as f:
        f.write(png_bytes(8, 8, lambda x, y: tuple(int(c * 255) for c in checker(x, y))))
    with open(os.path.join(unpacked, "textured.ash"), "w") as f:
        f.write(TEXTURED_ASH)

    stage, layer = new_stage()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.CreateFocalLengthAttr(35)
    cam.CreateHorizontalApertureAttr(36)
    cam.CreateVerticalApertureAttr(27)
    cam.AddTranslateOp().Set(Gf.Vec3d(0, 1.2, 4))
    cam.AddRotateXYZOp().Set(Gf.Vec3f(-15, 0, 0))
    # The light comes from a sublayer inside the package: sublayers resolve in-package too.
    lights_stage, lights = new_stage()
    UsdLux.DomeLight.Define(lights_stage, "/World/Sky").CreateIntensityAttr(1.0)
    lights.Export(os.path.join(unpacked, "lights.usda"), args={"format": "usda"})
    layer.subLayerPaths.append("lights.usda")
    floor = UsdGeom.Mesh.Define(stage, "/World/Floor")
    floor.CreatePointsAttr([(-2, 0, -2), (-2, 0, 2), (2, 0, 2), (2, 0, -2)])
    floor.CreateFaceVertexCountsAttr([4])
    floor.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    UsdGeom.PrimvarsAPI(floor).CreatePrimvar(
        "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex
    ).Set([(0, 0), (0, 1), (1, 1), (1, 0)])
    bind(floor.GetPrim(), "material:slotBinding:_000", "/Looks/Checker")
    ball = UsdGeom.Sphere.Define(stage, "/World/Ball")
    ball.CreateRadiusAttr(0.6)
    ball.AddTranslateOp().Set(Gf.Vec3d(0, 0.6, 0))
    bind(ball.GetPrim(), "material:slotBinding:_000", "/Looks/Matte")
    UsdGeom.Scope.Define(stage, "/Looks")
    material(stage, "/Looks/Checker", "textured", {"file": (Sdf.ValueTypeNames.Asset, Sdf.AssetPath("tex/checker.exr"))})
    material(stage, "/Looks/Matte", "matte", {"albedo": (Sdf.ValueTypeNames.Color3f, Gf.Vec3f(0.7, 0.7, 0.7))})
    export_twins(layer, "scene", unpacked)

    # The root layer first, as the usdz specification requires; Sdf's writer stores every
    # member uncompressed and 64-byte aligned.
    usdz = out("package.usdz")
    if os.path.exists(usdz):
        os.remove(usdz)
    with Sdf.ZipFileWriter.CreateNew(usdz) as writer:
        for member in ("scene.usdc", "lights.usda", "textured.ash", "tex/checker.exr", "tex/checker.png"):
            writer.AddFile(os.path.join(unpacked, member), member)
    os.remove(os.path.join(unpacked, "scene.usdc"))


def main():
    os.makedirs(OUT, exist_ok=True)
    layer = kitchen()
    export_twins(layer, "kitchen")
    layer.Export(out("kitchen_binary.usd"), args={"format": "usdc"})
    with open(out("textured.ash"), "w") as f:
        f.write(TEXTURED_ASH + """
override paint {
    output color albedo = color(0.8, 0.1, 0.1);
}

substance dirt {
    input float coverage = 0.5;
    node d = diffuse(albedo: color(0.2, 0.15, 0.1));
    node m = mask(opacity: coverage);
    surface = d.bsdf;
    mask = m.out;
}
""")
    arcs()
    package()
    for name in ("kitchen.usdc", "kitchen_binary.usd"):
        with open(out(name), "rb") as f:
            assert f.read(8) == b"PXR-USDC", name
    print("wrote", OUT)


if __name__ == "__main__":
    main()
