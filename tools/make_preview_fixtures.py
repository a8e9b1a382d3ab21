#!/usr/bin/env python3
"""Writes strata's UsdPreviewSurface / material:binding fixtures with Pixar's USD library
(pip install usd-core) into tests/fixtures/usd/preview/:

  checker.png       32 x 32 RGB, 8-bit: a 4 x 4 checker of 16 known colours, 8 x 8 texels per
                    cell (so bilinear filtering inside a cell returns the cell's colour exactly).
  textured.usda     a quad with primvars:st bound by material:binding to a UsdPreviewSurface
                    whose diffuseColor is a UsdUVTexture of checker.png read at the st that a
                    UsdPrimvarReader_float2 gives (its varname through a Material interface input).
  dirt.usda         the same, with a strata slot binding (_100, dirt.ash) over the right half.
  subset.usda       a two-face mesh bound to Blue; a GeomSubset (materialBind) binds face 1 to Red.
  strength.usda     strongerThanDescendants on an ancestor vs a descendant's own binding, purposes,
                    a metallic/roughness-only material and a collection-based binding.
  unknown_shader.usda  a Material whose surface is ND_standard_surface_surfaceshader (unknown to
                    strata before MaterialX; now its built-in standard_surface).
Each .usda is also exported as .usdc (for the binary-USD loader).

The camera looks down -z at the quad [-1, 1]^2 in the z = 0 plane from z = 5, with a 20 mm
aperture and a 50 mm focal length: the quad fills a square image exactly, so pixel (i, j) of a
W x W image sees st = ((i + 0.5) / W, 1 - (j + 0.5) / W).

Run it again whenever the fixtures must change; the Rust tests only read the written files.
"""
import os
import struct
import zlib

from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, Vt

HERE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "fixtures", "usd", "preview")

# Row-major from the image's top row: CELLS[row][col], 8-bit sRGB-encoded values.
CELLS = [
    [(255, 0, 0), (0, 255, 0), (0, 0, 255), (255, 255, 0)],
    [(255, 0, 255), (0, 255, 255), (128, 128, 128), (64, 32, 16)],
    [(200, 100, 50), (10, 20, 30), (250, 250, 250), (30, 200, 120)],
    [(100, 0, 200), (180, 180, 40), (0, 90, 180), (240, 160, 200)],
]
CELL = 8


def out(name):
    return os.path.join(HERE, name)


def write_checker_png(path):
    size = 4 * CELL
    raw = b""
    for y in range(size):
        row = b"\x00"  # filter type None
        for x in range(size):
            row += bytes(CELLS[y // CELL][x // CELL])
        raw += row

    def chunk(kind, data):
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", size, size, 8, 2, 0, 0, 0)
    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")
    with open(path, "wb") as f:
        f.write(png)


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


def quad(stage, path, split=False):
    """The quad [-1, 1]^2 at z = 0 with st = (x + 1) / 2, (y + 1) / 2; split: two faces (left, right)."""
    mesh = UsdGeom.Mesh.Define(stage, path)
    if split:
        pts = [(-1, -1, 0), (0, -1, 0), (1, -1, 0), (1, 1, 0), (0, 1, 0), (-1, 1, 0)]
        mesh.CreateFaceVertexCountsAttr([4, 4])
        mesh.CreateFaceVertexIndicesAttr([0, 1, 4, 5, 1, 2, 3, 4])
    else:
        pts = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]
        mesh.CreateFaceVertexCountsAttr([4])
        mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    mesh.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*p) for p in pts]))
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    st.Set(Vt.Vec2fArray([Gf.Vec2f((p[0] + 1) / 2, (p[1] + 1) / 2) for p in pts]))
    return mesh


def surface(stage, path):
    material = UsdShade.Material.Define(stage, path)
    pbr = UsdShade.Shader.Define(stage, path + "/PBR")
    pbr.CreateIdAttr("UsdPreviewSurface")
    material.CreateSurfaceOutput().ConnectToSource(pbr.CreateOutput("surface", Sdf.ValueTypeNames.Token))
    return material, pbr


def flat_material(stage, path, colour):
    material, pbr = surface(stage, path)
    pbr.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*colour))
    # ior 1: no Fresnel reflection, so the albedo AOV is the diffuse colour exactly.
    pbr.CreateInput("ior", Sdf.ValueTypeNames.Float).Set(1.0)
    return material


def textured_material(stage, path):
    material, pbr = surface(stage, path)
    pbr.CreateInput("ior", Sdf.ValueTypeNames.Float).Set(1.0)
    pbr.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.6)
    # The primvar name through an interface input, as DCC exporters write it.
    varname = material.CreateInput("frame:stPrimvarName", Sdf.ValueTypeNames.Token)
    varname.Set("st")
    reader = UsdShade.Shader.Define(stage, path + "/stReader")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).ConnectToSource(varname)
    texture = UsdShade.Shader.Define(stage, path + "/Checker")
    texture.CreateIdAttr("UsdUVTexture")
    texture.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("checker.png")
    texture.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(
        reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    )
    texture.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("repeat")
    texture.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("repeat")
    texture.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
    pbr.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
        texture.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    )
    return material


def bind(prim, material, strength=None, purpose=None):
    api = UsdShade.MaterialBindingAPI.Apply(prim.GetPrim())
    kwargs = {}
    if strength:
        kwargs["bindingStrength"] = strength
    if purpose:
        kwargs["materialPurpose"] = purpose
    api.Bind(material, **kwargs)


def strata_material(stage, path, asset, name):
    material = UsdShade.Material.Define(stage, path)
    shader = UsdShade.Shader.Define(stage, path + "/Shader")
    shader.SetSourceAsset(Sdf.AssetPath(asset), "strata")
    shader.SetSourceAssetSubIdentifier(name, "strata")
    return material


def save(stage, name):
    stage.GetRootLayer().Save()
    stage.GetRootLayer().Export(out(name.replace(".usda", ".usdc")))


def textured():
    stage = stage_with_camera("textured.usda")
    mesh = quad(stage, "/World/Quad")
    bind(mesh, textured_material(stage, "/Looks/Checker"))
    save(stage, "textured.usda")


def dirt():
    stage = stage_with_camera("dirt.usda")
    mesh = quad(stage, "/World/Quad")
    bind(mesh, textured_material(stage, "/Looks/Checker"))
    strata_material(stage, "/Looks/Dirt", "dirt.ash", "Dirt")
    mesh.GetPrim().CreateRelationship("material:slotBinding:_100").SetTargets([Sdf.Path("/Looks/Dirt")])
    save(stage, "dirt.usda")


def subset():
    stage = stage_with_camera("subset.usda")
    mesh = quad(stage, "/World/Quad", split=True)
    bind(mesh, flat_material(stage, "/Looks/Blue", (0.1, 0.2, 0.8)))
    right = UsdGeom.Subset.CreateGeomSubset(
        mesh, "RightFaces", UsdGeom.Tokens.face, Vt.IntArray([1]), "materialBind", UsdGeom.Tokens.nonOverlapping
    )
    bind(right, flat_material(stage, "/Looks/Red", (0.8, 0.1, 0.1)))
    save(stage, "subset.usda")


def strength():
    stage = stage_with_camera("strength.usda")
    green = flat_material(stage, "/Looks/Green", (0.1, 0.8, 0.1))
    red = flat_material(stage, "/Looks/Red", (0.8, 0.1, 0.1))
    strong = UsdGeom.Xform.Define(stage, "/World/Strong")
    bind(strong, green, strength=UsdShade.Tokens.strongerThanDescendants)
    bind(UsdGeom.Sphere.Define(stage, "/World/Strong/Ball"), red)
    weak = UsdGeom.Xform.Define(stage, "/World/Weak")
    bind(weak, green)
    bind(UsdGeom.Sphere.Define(stage, "/World/Weak/Ball"), red)
    # Purposes: full beats the all-purpose binding, which beats preview.
    purposes = UsdGeom.Sphere.Define(stage, "/World/Purposes")
    bind(purposes, red, purpose=UsdShade.Tokens.preview)
    bind(purposes, green, purpose=UsdShade.Tokens.full)
    # A metallic/roughness-only material.
    metal, pbr = surface(stage, "/Looks/Gold")
    pbr.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(1.0, 0.78, 0.34))
    pbr.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(1.0)
    pbr.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.25)
    bind(UsdGeom.Sphere.Define(stage, "/World/Gold"), metal)
    # A collection-based binding: /World/Coll binds Red directly and Green to the collection
    # `shiny` (A and below, minus A/Inner); A/Own's own direct binding is closer than both.
    coll = UsdGeom.Xform.Define(stage, "/World/Coll")
    shiny = Usd.CollectionAPI.Apply(coll.GetPrim(), "shiny")
    shiny.CreateIncludesRel().AddTarget("/World/Coll/A")
    shiny.CreateExcludesRel().AddTarget("/World/Coll/A/Inner")
    bind(coll, red)
    UsdShade.MaterialBindingAPI.Apply(coll.GetPrim()).Bind(shiny, green, "shinyBinding")
    UsdGeom.Xform.Define(stage, "/World/Coll/A")
    UsdGeom.Sphere.Define(stage, "/World/Coll/A/Ball")
    UsdGeom.Sphere.Define(stage, "/World/Coll/A/Inner")
    bind(UsdGeom.Sphere.Define(stage, "/World/Coll/A/Own"), metal)
    UsdGeom.Sphere.Define(stage, "/World/Coll/Other")
    save(stage, "strength.usda")


def unknown_shader():
    stage = stage_with_camera("unknown_shader.usda")
    mesh = quad(stage, "/World/Quad")
    material = UsdShade.Material.Define(stage, "/Looks/Standard")
    shader = UsdShade.Shader.Define(stage, "/Looks/Standard/Surface")
    shader.CreateIdAttr("ND_standard_surface_surfaceshader")
    material.CreateSurfaceOutput().ConnectToSource(shader.CreateOutput("out", Sdf.ValueTypeNames.Token))
    bind(mesh, material)
    save(stage, "unknown_shader.usda")


if __name__ == "__main__":
    os.makedirs(HERE, exist_ok=True)
    write_checker_png(out("checker.png"))
    with open(out("dirt.ash"), "w") as f:
        f.write(
            "// Dirt over the right half (u >= 0.5) of whatever is below it.\n"
            "shader right_half(float s = u, output float out) {\n"
            "    out = s >= 0.5 ? 1.0 : 0.0;\n"
            "}\n\n"
            "substance Dirt {\n"
            "    input color albedo = color(0.35, 0.25, 0.1);\n"
            "    node bsdf = diffuse(albedo: albedo);\n"
            "    node region = right_half();\n"
            "    surface = bsdf.bsdf;\n"
            "    mask = region.out;\n"
            "}\n"
        )
    textured()
    dirt()
    subset()
    strength()
    unknown_shader()
