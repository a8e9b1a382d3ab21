#!/usr/bin/env python3
"""Writes a chess-set-like production asset (issue 24's target) with Pixar's USD library
(pip install usd-core; numpy) into OUTDIR, for measuring `strata check` and `strata render`:

  chess.usdc        a board (a 64 x 64 quad grid) and 32 lathed pieces of 96 x 128 quads:
                    about 400k faces; a camera, a dome and a distant light.
  tex/*.png         40 textures of 2048 x 2048, 8 materials x 5 maps: diffuseColor (sRGB RGB),
                    roughness, metallic, clearcoat (grey, raw) and a tangent-space normal map
                    (RGB, raw). Written as PNG (no JPEG encoder without extra packages).
  chess.usda        the same stage as text (only with --usda; about 40 MB).

Nothing here is committed output: tests and measurements write it into a temporary directory.

    /work/venv/bin/python tools/make_chess_asset.py OUTDIR [--usda]
"""
import math
import os
import struct
import sys
import zlib

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, Vt

SIDE = 2048
SEGMENTS = 96  # around a piece
RINGS = 128  # along its profile
MATERIALS = 8
MAPS = [("diffuseColor", 3, "sRGB"), ("roughness", 1, "raw"), ("metallic", 1, "raw"),
        ("clearcoat", 1, "raw"), ("normal", 3, "raw")]


def write_png(path, pixels):
    """An 8-bit PNG of an (h, w) or (h, w, c) uint8 array."""
    h, w = pixels.shape[:2]
    channels = 1 if pixels.ndim == 2 else pixels.shape[2]
    color = {1: 0, 3: 2, 4: 6}[channels]
    rows = pixels.reshape(h, w * channels)
    raw = np.concatenate([np.zeros((h, 1), np.uint8), rows], axis=1).tobytes()

    def chunk(kind, data):
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", w, h, 8, color, 0, 0, 0)
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw, 1)) + chunk(b"IEND", b""))


def texture(rng, material, channels):
    """Wood-or-marble-like detail: coarse noise upsampled, fine noise and veins."""
    coarse = rng.random((64, 64, channels))
    img = np.kron(coarse, np.ones((SIDE // 64, SIDE // 64, 1)))
    y, x = np.mgrid[0:SIDE, 0:SIDE]
    veins = 0.5 + 0.5 * np.sin((x * 0.02 + y * 0.005 + 3 * img[..., 0]) * (1 + material % 3))
    img = 0.45 * img + 0.35 * veins[..., None] + 0.2 * rng.random((SIDE, SIDE, channels))
    img = (np.clip(img, 0, 1) * 255).astype(np.uint8)
    return img[..., 0] if channels == 1 else img


def lathe(radius_at, height):
    """A surface of revolution: points, face counts and indices (quads)."""
    t = np.linspace(0.0, 1.0, RINGS + 1)
    a = np.linspace(0.0, 2 * math.pi, SEGMENTS, endpoint=False)
    r = np.array([radius_at(v) for v in t])
    px = (r[:, None] * np.cos(a)[None, :]).ravel()
    pz = (r[:, None] * np.sin(a)[None, :]).ravel()
    py = np.repeat(t * height, SEGMENTS)
    points = np.stack([px, py, pz], axis=1).astype(np.float32)
    i, j = np.mgrid[0:RINGS, 0:SEGMENTS]
    a0 = i * SEGMENTS + j
    a1 = i * SEGMENTS + (j + 1) % SEGMENTS
    quads = np.stack([a0, a1, a1 + SEGMENTS, a0 + SEGMENTS], axis=-1).reshape(-1).astype(np.int32)
    st = np.stack([np.tile(np.arange(SEGMENTS) / SEGMENTS, RINGS + 1), np.repeat(t, SEGMENTS)], axis=1)
    return points, quads, st.astype(np.float32)


def bind(stage, prim, material):
    UsdShade.MaterialBindingAPI.Apply(prim).Bind(material)


def main():
    out = sys.argv[1]
    os.makedirs(os.path.join(out, "tex"), exist_ok=True)
    rng = np.random.default_rng(24)
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    stage.SetDefaultPrim(stage.DefinePrim("/Chess", "Xform"))
    materials = []
    for m in range(MATERIALS):
        mat = UsdShade.Material.Define(stage, f"/Chess/Looks/M{m}")
        pbr = UsdShade.Shader.Define(stage, f"/Chess/Looks/M{m}/PBR")
        pbr.CreateIdAttr("UsdPreviewSurface")
        reader = UsdShade.Shader.Define(stage, f"/Chess/Looks/M{m}/St")
        reader.CreateIdAttr("UsdPrimvarReader_float2")
        reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")
        st = reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
        for name, channels, space in MAPS:
            file = f"tex/m{m}_{name}.png"
            write_png(os.path.join(out, file), texture(rng, m, channels))
            tex = UsdShade.Shader.Define(stage, f"/Chess/Looks/M{m}/{name}")
            tex.CreateIdAttr("UsdUVTexture")
            tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(file)
            tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set(space)
            tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(st)
            if channels == 3:
                rgb = tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
                kind = Sdf.ValueTypeNames.Normal3f if name == "normal" else Sdf.ValueTypeNames.Color3f
                if name == "normal":
                    tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(2, 2, 2, 1))
                    tex.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(-1, -1, -1, 0))
                pbr.CreateInput(name, kind).ConnectToSource(rgb)
            else:
                r = tex.CreateOutput("r", Sdf.ValueTypeNames.Float)
                pbr.CreateInput(name, Sdf.ValueTypeNames.Float).ConnectToSource(r)
        mat.CreateSurfaceOutput().ConnectToSource(pbr.ConnectableAPI(), "surface")
        materials.append(mat)

    def mesh(path, points, quads, st, material):
        m = UsdGeom.Mesh.Define(stage, path)
        # Polygonal, as exported game and scan assets are (USD's default would subdivide).
        m.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        m.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points))
        m.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(quads) // 4, 4, np.int32)))
        m.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(quads))
        pv = UsdGeom.PrimvarsAPI(m).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
        pv.Set(Vt.Vec2fArray.FromNumpy(st))
        bind(stage, m.GetPrim(), material)
        return m

    # The board: 64 x 64 quads over 8 x 8 units, its st tiling each square once.
    n = 64
    y, x = np.mgrid[0:n + 1, 0:n + 1]
    points = np.stack([x * 8.0 / n - 4, np.zeros_like(x, float), y * 8.0 / n - 4], axis=-1).reshape(-1, 3)
    i, j = np.mgrid[0:n, 0:n]
    a0 = i * (n + 1) + j
    quads = np.stack([a0, a0 + n + 1, a0 + n + 2, a0 + 1], axis=-1).reshape(-1).astype(np.int32)
    st = np.stack([x.ravel() * 8.0 / n, y.ravel() * 8.0 / n], axis=1)
    mesh("/Chess/Board", points.astype(np.float32), quads, st.astype(np.float32), materials[MATERIALS - 1])

    profiles = [
        lambda t: 0.30 - 0.12 * t + 0.05 * math.sin(12 * t),  # pawn
        lambda t: 0.33 - 0.10 * t + 0.08 * math.cos(9 * t),  # rook
        lambda t: 0.32 - 0.14 * t + 0.06 * math.sin(15 * t),  # knight
        lambda t: 0.32 - 0.18 * t + 0.05 * math.sin(20 * t),  # bishop
        lambda t: 0.36 - 0.15 * t + 0.07 * math.sin(11 * t),  # queen
        lambda t: 0.36 - 0.13 * t + 0.07 * math.cos(13 * t),  # king
    ]
    back = [1, 2, 3, 4, 5, 3, 2, 1]
    for side, (row_back, row_pawn) in enumerate([(0, 1), (7, 6)]):
        for col in range(8):
            for row, kind in [(row_back, back[col]), (row_pawn, 0)]:
                height = 0.6 + 0.15 * kind
                points, quads, st = lathe(lambda t, k=kind: max(0.05, profiles[k](t)), height)
                points = points + np.array([col - 3.5, 0.0, row - 3.5], np.float32)
                material = materials[(kind % 3) + 3 * side]
                mesh(f"/Chess/S{side}_{row}_{col}", points, quads, st, material)

    cam = UsdGeom.Camera.Define(stage, "/Chess/Camera")
    cam.CreateFocalLengthAttr(35)
    xf = UsdGeom.Xformable(cam)
    xf.AddTranslateOp().Set(Gf.Vec3d(0, 6, 9))
    xf.AddRotateXYZOp().Set(Gf.Vec3f(-32, 0, 0))
    UsdLux.DomeLight.Define(stage, "/Chess/Sky").CreateIntensityAttr(0.5)
    sun = UsdLux.DistantLight.Define(stage, "/Chess/Sun")
    sun.CreateIntensityAttr(3)
    UsdGeom.Xformable(sun).AddRotateXYZOp().Set(Gf.Vec3f(-50, 30, 0))
    stage.GetRootLayer().Export(os.path.join(out, "chess.usdc"))
    if "--usda" in sys.argv:
        stage.GetRootLayer().Export(os.path.join(out, "chess.usda"))
    faces = sum(len(UsdGeom.Mesh(p).GetFaceVertexCountsAttr().Get()) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh))
    print(f"{faces} faces, {MATERIALS * len(MAPS)} textures of {SIDE}x{SIDE} in {out}")


if __name__ == "__main__":
    main()
