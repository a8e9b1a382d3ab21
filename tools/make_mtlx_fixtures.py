#!/usr/bin/env python3
"""Writes strata's MaterialX fixtures into tests/fixtures/mtlx/ with the MaterialX Python package
(pip install MaterialX) for the documents and Pixar's USD library (pip install usd-core) for the
scenes:

  textures/*.png      tiny 16 x 16 RGB textures, 2 x 2 cells of 8 x 8 texels (bilinear lookups
                      inside a cell return the cell's value exactly): base colour (sRGB), roughness,
                      metalness (0 or 1 per cell), tangent-space normal.
  chess_mat.mtlx      an OpenPBR "chess piece" material: a node graph of image nodes (base colour
                      as srgb_texture, roughness, metalness, a normal map through `normalmap`) with
                      the document's `fileprefix` = "textures/", written by MaterialX itself.
  chess_mat.expected  MaterialX's own reading of chess_mat.mtlx: per node its path and the node
                      definition MaterialX resolves it to (`getNodeDef()`, the standard library
                      loaded), and per connected input where it reads. strata's translation must
                      name the same definitions and connections.
  layered_mat.mtlx    a hand-written pbrlib graph (layer, mix, add and multiply over dielectric,
                      Oren-Nayar, sheen and conductor lobes, a uniform EDF through `surface`) and
                      a half-weight clear coat over white Lambert; layered_mat.expected is
                      MaterialX's reading of it, as for chess_mat.
  chess.usda          a quad under a camera bound to </Looks/M_piece>, `Looks` referencing
                      @chess_mat.mtlx@</MaterialX/Materials>.
  chess_preview.usda  the same quad with the same textures as a UsdPreviewSurface network: the
                      translation strata must render like (within noise).
  odd/*.mtlx          malformed and odd documents, each with MaterialX's verdict in
                      odd/verdicts.txt (whether MaterialX's XML reader accepts it).
  upgrade/*.upgraded.mtlx
                      each 1.38 document in upgrade/ (MaterialX's own thin_film_bsdf test
                      document, and the hand-written thin_film_bindings_1_38.mtlx) as MaterialX
                      reads it: upgraded to 1.39, thin-film layers folded into the BSDFs below.

The camera looks down -z at the quad [-1, 1]^2 in the z = 0 plane from z = 5 (20 mm aperture,
50 mm focal length): the quad fills a square image exactly.

Run it again whenever the fixtures must change; the Rust tests only read the written files.
"""
import os
import struct
import zlib

import MaterialX as mx
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, Vt

HERE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "fixtures", "mtlx")
CELL = 8


def out(*name):
    path = os.path.join(HERE, *name)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    return path


def write_png(path, cells):
    """cells[row][col]: 8-bit RGB of each 8 x 8 cell, top row first."""
    size = len(cells) * CELL
    raw = b""
    for y in range(size):
        raw += b"\x00" + b"".join(bytes(cells[y // CELL][x // CELL]) for x in range(size))

    def chunk(kind, data):
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", size, size, 8, 2, 0, 0, 0)
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


TEXTURES = {
    "base.png": [[(200, 40, 30), (240, 230, 210)], [(30, 30, 35), (90, 160, 60)]],
    "rough.png": [[(40, 40, 40), (200, 200, 200)], [(120, 120, 120), (20, 20, 20)]],
    "metal.png": [[(0, 0, 0), (255, 255, 255)], [(0, 0, 0), (255, 255, 255)]],
    "normal.png": [[(128, 128, 255), (180, 128, 230)], [(128, 80, 240), (128, 128, 255)]],
}


def chess_document():
    doc = mx.createDocument()
    doc.setFilePrefix("textures/")
    ng = doc.addNodeGraph("NG_piece")
    outputs = {}
    for name, file, ty, space in [
        ("img_base", "base.png", "color3", "srgb_texture"),
        ("img_rough", "rough.png", "float", None),
        ("img_metal", "metal.png", "float", None),
        ("img_normal", "normal.png", "vector3", None),
    ]:
        node = ng.addNode("image", name, ty)
        f = node.addInput("file", "filename")
        f.setValueString(file)
        if space:
            f.setColorSpace(space)
        outputs[name] = node
    normalmap = ng.addNode("normalmap", "normalmap", "vector3")
    normalmap.addInput("in", "vector3").setConnectedNode(outputs["img_normal"])
    graph_outputs = {}
    for out_name, node, ty in [
        ("out_base", outputs["img_base"], "color3"),
        ("out_rough", outputs["img_rough"], "float"),
        ("out_metal", outputs["img_metal"], "float"),
        ("out_normal", normalmap, "vector3"),
    ]:
        o = ng.addOutput(out_name, ty)
        o.setConnectedNode(node)
        graph_outputs[out_name] = o
    sr = doc.addNode("open_pbr_surface", "SR_piece", "surfaceshader")
    for input_name, ty, o in [
        ("base_color", "color3", "out_base"),
        ("specular_roughness", "float", "out_rough"),
        ("base_metalness", "float", "out_metal"),
        ("geometry_normal", "vector3", "out_normal"),
    ]:
        sr.addInput(input_name, ty).setConnectedOutput(graph_outputs[o])
    doc.addMaterialNode("M_piece", sr)
    return doc


def layered_document():
    """A hand-written pbrlib graph: mix(fg = sheen, bg = layer(dielectric, oren_nayar), 0.25) · 0.6
    + conductor · (0.2, 0.3, 0.4) (weights summing to at most 1), with a uniform EDF; and a
    half-weight clear coat over white Lambert."""
    doc = mx.createDocument()

    def bsdf(name, category, inputs):
        node = doc.addNode(category, name, "BSDF")
        for input_name, ty, value in inputs:
            i = node.addInput(input_name, ty)
            if isinstance(value, mx.Node):
                i.setConnectedNode(value)
            else:
                i.setValueString(value)
        return node

    coat = bsdf("coat", "dielectric_bsdf", [("ior", "float", "1.5"), ("roughness", "vector2", "0.04, 0.04")])
    base = bsdf("base", "oren_nayar_diffuse_bsdf", [("color", "color3", "0.8, 0.5, 0.2"), ("roughness", "float", "0.3")])
    coated = bsdf("coated", "layer", [("top", "BSDF", coat), ("base", "BSDF", base)])
    fuzz = bsdf("fuzz", "sheen_bsdf", [("color", "color3", "0.9, 0.9, 1"), ("roughness", "float", "0.4")])
    mixed = bsdf("mixed", "mix", [("fg", "BSDF", fuzz), ("bg", "BSDF", coated), ("mix", "float", "0.25")])
    metal = bsdf("metal", "conductor_bsdf", [("roughness", "vector2", "0.09, 0.09")])
    tinted = bsdf("tinted", "multiply", [("in1", "BSDF", metal), ("in2", "color3", "0.2, 0.3, 0.4")])
    scaled = bsdf("scaled", "multiply", [("in1", "BSDF", mixed), ("in2", "float", "0.6")])
    total = bsdf("total", "add", [("in1", "BSDF", scaled), ("in2", "BSDF", tinted)])
    glow = doc.addNode("uniform_edf", "glow", "EDF")
    glow.addInput("color", "color3").setValueString("0.5, 0.25, 0")
    surface = doc.addNode("surface", "SR_layered", "surfaceshader")
    surface.addInput("bsdf", "BSDF").setConnectedNode(total)
    surface.addInput("edf", "EDF").setConnectedNode(glow)
    doc.addMaterialNode("M_layered", surface)

    white = bsdf("white", "oren_nayar_diffuse_bsdf", [("color", "color3", "1, 1, 1")])
    clear = bsdf("clear", "dielectric_bsdf", [("ior", "float", "1.5"), ("roughness", "vector2", "0.09, 0.09")])
    half = bsdf("half", "multiply", [("in1", "BSDF", clear), ("in2", "float", "0.5")])
    furnace = bsdf("furnace", "layer", [("top", "BSDF", half), ("base", "BSDF", white)])
    surface = doc.addNode("surface", "SR_furnace", "surfaceshader")
    surface.addInput("bsdf", "BSDF").setConnectedNode(furnace)
    doc.addMaterialNode("M_furnace", surface)
    return doc


def describe(doc_path):
    """MaterialX's reading of a document: nodes with their node definitions, and connections."""
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, doc_path)
    own = [e.getNamePath() for e in doc.traverseTree() if isinstance(e, mx.Node) and e.getType() != "material"]
    stdlib = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), stdlib)
    doc.importLibrary(stdlib)
    valid, message = doc.validate()
    assert valid, message
    lines = []
    for path in own:
        elem = doc.getDescendant(path)
        nd = elem.getNodeDef()
        lines.append(f"node {path} {nd.getName() if nd else '?'}")
        for i in elem.getInputs():
            if i.getNodeName():
                lines.append(f"connect {path}.{i.getName()} node {i.getNodeName()} {i.getOutputString() or 'out'}")
            elif i.getNodeGraphString():
                lines.append(f"connect {path}.{i.getName()} graph {i.getNodeGraphString()} {i.getOutputString()}")
    return sorted(set(lines))


def quad_stage(path):
    stage = Usd.Stage.CreateNew(path)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    cam = UsdGeom.Camera.Define(stage, "/Camera")
    cam.AddTranslateOp().Set(Gf.Vec3d(0, 0, 5))
    cam.GetFocalLengthAttr().Set(50.0)
    cam.GetHorizontalApertureAttr().Set(20.0)
    cam.GetVerticalApertureAttr().Set(20.0)
    light = UsdLux.DistantLight.Define(stage, "/Sun")
    light.GetIntensityAttr().Set(3.0)
    light.AddRotateXYZOp().Set(Gf.Vec3f(-20, 25, 0))
    UsdLux.DomeLight.Define(stage, "/Sky").GetIntensityAttr().Set(0.5)
    mesh = UsdGeom.Mesh.Define(stage, "/Piece")
    mesh.GetPointsAttr().Set(Vt.Vec3fArray([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]))
    mesh.GetFaceVertexCountsAttr().Set([4])
    mesh.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3])
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    st.Set(Vt.Vec2fArray([(0, 0), (1, 0), (1, 1), (0, 1)]))
    return stage, mesh


def chess_scene():
    stage, mesh = quad_stage(out("chess.usda"))
    looks = stage.DefinePrim("/Looks", "Scope")
    looks.GetReferences().AddReference("./chess_mat.mtlx", "/MaterialX/Materials")
    # usd-core ships without the usdMtlx plugin, so the material is not on its stage: the
    # binding is authored as the relationship UsdShade would write.
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())
    mesh.GetPrim().CreateRelationship("material:binding").SetTargets([Sdf.Path("/Looks/M_piece")])
    stage.GetRootLayer().Save()


def preview_scene():
    stage, mesh = quad_stage(out("chess_preview.usda"))
    material = UsdShade.Material.Define(stage, "/Looks/Preview")
    surface = UsdShade.Shader.Define(stage, "/Looks/Preview/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    reader = UsdShade.Shader.Define(stage, "/Looks/Preview/St")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")
    reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    for name, file, space, channel, target, ty in [
        ("Base", "base.png", "sRGB", "rgb", "diffuseColor", Sdf.ValueTypeNames.Color3f),
        ("Rough", "rough.png", "raw", "r", "roughness", Sdf.ValueTypeNames.Float),
        ("Metal", "metal.png", "raw", "r", "metallic", Sdf.ValueTypeNames.Float),
        ("Normal", "normal.png", "raw", "rgb", "normal", Sdf.ValueTypeNames.Normal3f),
    ]:
        tex = UsdShade.Shader.Define(stage, f"/Looks/Preview/{name}")
        tex.CreateIdAttr("UsdUVTexture")
        tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(f"./textures/{file}")
        tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set(space)
        tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
        if name == "Normal":
            tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(2, 2, 2, 1))
            tex.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(-1, -1, -1, 0))
        out_ty = Sdf.ValueTypeNames.Float3 if channel == "rgb" else Sdf.ValueTypeNames.Float
        tex.CreateOutput(channel, out_ty)
        surface.CreateInput(target, ty).ConnectToSource(tex.ConnectableAPI(), channel)
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    stage.GetRootLayer().Save()


# Odd and malformed documents: name -> text. Each must compile or give a clear diagnostic.
ODD = {
    "unclosed": '<?xml version="1.0"?>\n<materialx version="1.39">\n  <nodegraph name="NG">\n    <image name="i" type="color3">\n  </nodegraph>\n</materialx>\n',
    "not_materialx": '<?xml version="1.0"?>\n<usd version="1"/>\n',
    "entity": '<?xml version="1.0"?>\n<!DOCTYPE materialx [<!ENTITY a "aaaaaaaa">]>\n<materialx version="1.39">&a;</materialx>\n',
    "empty": '<?xml version="1.0"?>\n<materialx version="1.39"/>\n',
    "unknown_node": """<?xml version="1.0"?>
<materialx version="1.39">
  <nodegraph name="NG">
    <blur name="adjust" type="color3">
      <input name="in" type="color3" value="0.5, 0.2, 0.1" />
    </blur>
    <output name="out" type="color3" nodename="adjust" />
  </nodegraph>
  <open_pbr_surface name="SR" type="surfaceshader">
    <input name="base_color" type="color3" nodegraph="NG" output="out" />
  </open_pbr_surface>
  <surfacematerial name="M" type="material">
    <input name="surfaceshader" type="surfaceshader" nodename="SR" />
  </surfacematerial>
</materialx>
""",
    "color4": """<?xml version="1.0"?>
<materialx version="1.39">
  <constant name="c4" type="color4">
    <input name="value" type="color4" value="1, 0, 0, 1" />
  </constant>
  <standard_surface name="SR" type="surfaceshader">
    <input name="opacity" type="color3" value="1, 1, 1" />
  </standard_surface>
  <surfacematerial name="M" type="material">
    <input name="surfaceshader" type="surfaceshader" nodename="SR" />
  </surfacematerial>
</materialx>
""",
    "dangling": """<?xml version="1.0"?>
<materialx version="1.39">
  <standard_surface name="SR" type="surfaceshader">
    <input name="base_color" type="color3" nodename="missing" />
    <input name="base" type="float" value="not a number" />
  </standard_surface>
  <surfacematerial name="M" type="material">
    <input name="surfaceshader" type="surfaceshader" nodename="SR" />
  </surfacematerial>
</materialx>
""",
    "unsupported_lobes": """<?xml version="1.0"?>
<materialx version="1.39">
  <standard_surface name="SR" type="surfaceshader">
    <input name="sheen" type="float" value="0.5" />
    <input name="coat_affect_color" type="float" value="0.5" />
    <input name="metalness" type="float" value="0.3" />
  </standard_surface>
  <surfacematerial name="M" type="material">
    <input name="surfaceshader" type="surfaceshader" nodename="SR" />
  </surfacematerial>
</materialx>
""",
}


def verdicts():
    lines = []
    for name, text in sorted(ODD.items()):
        with open(out("odd", f"{name}.mtlx"), "w") as f:
            f.write(text)
        doc = mx.createDocument()
        try:
            mx.readFromXmlString(doc, text)
            lines.append(f"{name} read")
        except Exception:
            lines.append(f"{name} rejected")
    with open(out("odd", "verdicts.txt"), "w") as f:
        f.write("\n".join(lines) + "\n")


def upgrades():
    for name in ["thin_film_bsdf_1_38", "thin_film_bindings_1_38"]:
        doc = mx.createDocument()
        mx.readFromXmlFile(doc, out("upgrade", f"{name}.mtlx"))
        assert doc.getVersionString() == "1.39"
        mx.writeToXmlFile(doc, out("upgrade", f"{name}.upgraded.mtlx"))


def main():
    for name, cells in TEXTURES.items():
        write_png(out("textures", name), cells)
    for name, doc in [("chess_mat", chess_document()), ("layered_mat", layered_document())]:
        valid, message = doc.validate()
        assert valid, message
        mx.writeToXmlFile(doc, out(f"{name}.mtlx"))
        with open(out(f"{name}.expected"), "w") as f:
            f.write("\n".join(describe(out(f"{name}.mtlx"))) + "\n")
    chess_scene()
    preview_scene()
    verdicts()
    upgrades()


if __name__ == "__main__":
    main()
