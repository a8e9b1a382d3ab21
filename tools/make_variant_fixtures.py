#!/usr/bin/env python3
"""Writes the composition fixtures of tests/compose_usd.rs and the answers Pixar's USD
library gives for them (`pip install usd-core`), so strata is checked against USD, never
against itself:

tests/fixtures/variants/       variant cases (issue 19, item 6)
  nested2         a selection authored inside a variant (the issue's minimal case)
  nested3         selections three variants deep, values set at every depth, and a
                  stronger selection authored outside beating one inside a variant
  split_refs      one variant set whose variants come from two references
  split_local     one variant set defined partly in a referenced asset, partly locally
  strength        selections through a reference, an inherit and two sublayers: the
                  stronger layer's selection wins, the referencing layer's beats the asset's
  missing         a selection naming a variant no arc offers (strata must still warn)
  through_arcs    a variant adding a reference whose asset's set it selects, a class's set
                  selected by the inheriting prim, a set on a prim inside a variant

tests/fixtures/compose_around/ what USD composes around (issue 19, item 1)
  missing_sublayer     a sublayer that does not resolve
  missing_reference    a reference and a payload to files that do not resolve
  missing_prim         references and a payload to prims that do not exist, a layer with
                       no defaultPrim
  binding_missing      `material:binding` and a slot binding to prims that do not exist
  materialx            a MaterialX document referenced as a layer: usd-core has no MaterialX
                       plugin here, so no .expected (tests/mtlx/ checks what strata reads)
  malformed            a referenced layer with a syntax error

For each case CASE.usda (plus the layers it names), CASE.expected holds what usd-core
composes, one fact per line:

    prim PATH                  every prim of Usd.Stage.Traverse(), in traversal order
    value PATH.ATTR VALUE      an attribute value (Get() at the default time)
    bound PATH MATERIAL|-      UsdShade ComputeBoundMaterial of a renderable prim
    warning TEXT               a diagnostic strata must report as a warning (not from USD:
                               what issue 19 asks strata to say)

Run from the repository root: python3 tools/make_variant_fixtures.py
"""
import os
import textwrap

from pxr import Usd, UsdGeom, UsdShade

ROOT = os.path.join("tests", "fixtures")


def write(folder, name, text):
    os.makedirs(folder, exist_ok=True)
    with open(os.path.join(folder, name), "w") as f:
        f.write(textwrap.dedent(text).lstrip("\n"))


def expected(folder, case, values=(), warnings=(), bindings=False):
    """Opens CASE.usda with usd-core and writes CASE.expected."""
    path = os.path.join(folder, case + ".usda")
    stage = Usd.Stage.Open(path)
    lines = [f"# {case}.usda composed by usd-core {'.'.join(map(str, Usd.GetVersion()))}"]
    prims = list(stage.Traverse())
    lines += [f"prim {p.GetPath()}" for p in prims]
    for attr_path in values:
        prim_path, attr = attr_path.split(".", 1)
        value = stage.GetPrimAtPath(prim_path).GetAttribute(attr).Get()
        lines.append(f"value {attr_path} {value}")
    if bindings:
        for p in prims:
            if p.IsA(UsdGeom.Gprim):
                material, _ = UsdShade.MaterialBindingAPI(p).ComputeBoundMaterial()
                lines.append(f"bound {p.GetPath()} {material.GetPath() if material else '-'}")
    lines += [f"warning {w}" for w in warnings]
    with open(os.path.join(folder, case + ".expected"), "w") as f:
        f.write("\n".join(lines) + "\n")


def variants():
    d = os.path.join(ROOT, "variants")
    write(d, "nested2.usda", '''
        #usda 1.0
        (
            defaultPrim = "A"
        )

        def Xform "A" (
            variants = {
                string outer = "x"
            }
            prepend variantSets = "outer"
        )
        {
            variantSet "outer" = {
                "x" (
                    variants = {
                        string inner = "b"
                    }
                    prepend variantSets = "inner"
                ) {
                    variantSet "inner" = {
                        "a" {
                            def Sphere "SA"
                            {
                            }
                        }
                        "b" {
                            def Sphere "SB"
                            {
                            }
                        }
                    }
                }
            }
        }
    ''')
    expected(d, "nested2")

    write(d, "nested3.usda", '''
        #usda 1.0
        (
            defaultPrim = "Ball"
        )

        def Xform "Ball" (
            variants = {
                string shape = "round"
            }
            prepend variantSets = "shape"
        )
        {
            variantSet "shape" = {
                "flat" {
                    def Cube "Flat"
                    {
                    }
                }
                "round" (
                    variants = {
                        string size = "big"
                    }
                    prepend variantSets = "size"
                ) {
                    double level = 1
                    def Sphere "Core"
                    {
                        double radius = 1
                    }
                    variantSet "size" = {
                        "big" (
                            variants = {
                                string finish = "rough"
                            }
                            prepend variantSets = "finish"
                        ) {
                            double level = 2
                            def Sphere "Core"
                            {
                                double radius = 3
                            }
                            variantSet "finish" = {
                                "rough" {
                                    double level = 3
                                    def Sphere "Core"
                                    {
                                        float roughness = 0.75
                                    }
                                    def Mesh "Bumps"
                                    {
                                    }
                                }
                                "smooth" {
                                    def Mesh "Polish"
                                    {
                                    }
                                }
                            }
                        }
                        "small" {
                            def Sphere "Core"
                            {
                                double radius = 0.5
                            }
                        }
                    }
                }
            }
        }

        def "Twin" (
            prepend references = </Ball>
            variants = {
                string size = "small"
            }
        )
        {
        }
    ''')
    expected(d, "nested3", values=["/Ball.level", "/Ball/Core.radius", "/Ball/Core.roughness",
                                   "/Twin.level", "/Twin/Core.radius"])

    write(d, "quad_a.usda", '''
        #usda 1.0
        (
            defaultPrim = "Asset"
        )

        def Xform "Asset" (
            prepend variantSets = "quad_creases"
        )
        {
            variantSet "quad_creases" = {
                "off" {
                    def Mesh "Plain"
                    {
                    }
                }
            }
        }
    ''')
    write(d, "quad_b.usda", '''
        #usda 1.0
        (
            defaultPrim = "Asset"
        )

        def Xform "Asset" (
            prepend variantSets = "quad_creases"
        )
        {
            variantSet "quad_creases" = {
                "on" {
                    custom int creased = 1
                    def Mesh "Creased"
                    {
                    }
                }
            }
        }
    ''')
    write(d, "split_refs.usda", '''
        #usda 1.0

        def Xform "Quad" (
            prepend references = [@./quad_a.usda@, @./quad_b.usda@]
            variants = {
                string quad_creases = "on"
            }
            prepend variantSets = "quad_creases"
        )
        {
        }
    ''')
    expected(d, "split_refs", values=["/Quad.creased"])

    write(d, "look_asset.usda", '''
        #usda 1.0
        (
            defaultPrim = "Thing"
        )

        def Xform "Thing" (
            variants = {
                string look = "red"
            }
            prepend variantSets = "look"
        )
        {
            variantSet "look" = {
                "red" {
                    color3f tint = (1, 0, 0)
                }
                "blue" {
                    color3f tint = (0, 0, 1)
                }
                "green" {
                    color3f tint = (0, 1, 0)
                }
            }
        }
    ''')
    write(d, "split_local.usda", '''
        #usda 1.0

        def Xform "Thing" (
            prepend references = @./look_asset.usda@
            prepend variantSets = "look"
            variants = {
                string look = "blue"
            }
        )
        {
            variantSet "look" = {
                "local_only" {
                    def Sphere "LocalOnly"
                    {
                    }
                }
            }
        }

        def Xform "Local" (
            prepend references = @./look_asset.usda@
            prepend variantSets = "look"
            variants = {
                string look = "local_only"
            }
        )
        {
            variantSet "look" = {
                "local_only" {
                    def Sphere "LocalOnly"
                    {
                    }
                }
            }
        }
    ''')
    expected(d, "split_local", values=["/Thing.tint"])

    write(d, "strength_strong.usda", '''
        #usda 1.0

        over "ByLayers" (
            variants = {
                string look = "green"
            }
        )
        {
        }
    ''')
    write(d, "strength_weak.usda", '''
        #usda 1.0

        over "ByLayers" (
            variants = {
                string look = "blue"
            }
        )
        {
        }
    ''')
    write(d, "strength.usda", '''
        #usda 1.0
        (
            subLayers = [
                @./strength_strong.usda@,
                @./strength_weak.usda@
            ]
        )

        class "_look_blue" (
            variants = {
                string look = "blue"
            }
        )
        {
        }

        def Xform "AssetDefault" (
            prepend references = @./look_asset.usda@
        )
        {
        }

        def Xform "Referencing" (
            prepend references = @./look_asset.usda@
            variants = {
                string look = "green"
            }
        )
        {
        }

        def Xform "ByInherit" (
            prepend inherits = </_look_blue>
            prepend references = @./look_asset.usda@
        )
        {
        }

        def Xform "ByLayers" (
            prepend references = @./look_asset.usda@
        )
        {
        }
    ''')
    expected(d, "strength", values=["/AssetDefault.tint", "/Referencing.tint", "/ByInherit.tint", "/ByLayers.tint"])

    write(d, "missing.usda", '''
        #usda 1.0

        def Xform "Thing" (
            prepend references = @./look_asset.usda@
            prepend variantSets = "look"
            variants = {
                string look = "purple"
            }
        )
        {
        }
    ''')
    expected(d, "missing", values=["/Thing.tint"],
             warnings=["variant `purple` selected for `look` on `/Thing` does not exist"])


def variants_through_arcs():
    """Variants reached through other arcs: a variant that adds a reference to an asset with
    its own variants (selected from inside the variant), a class's variant set selected by
    the inheriting prim, a child prim with its own set inside a variant."""
    d = os.path.join(ROOT, "variants")
    write(d, "through_arcs.usda", '''
        #usda 1.0

        class "_shaded" (
            prepend variantSets = "shade"
        )
        {
            variantSet "shade" = {
                "matte" {
                    float roughness = 1
                }
                "gloss" {
                    float roughness = 0.1
                }
            }
        }

        def Xform "Shelf" (
            prepend variantSets = "contents"
            variants = {
                string contents = "pot"
            }
        )
        {
            variantSet "contents" = {
                "empty" {
                }
                "pot" (
                    prepend references = @./look_asset.usda@
                    variants = {
                        string look = "green"
                    }
                ) {
                    def Xform "Lid" (
                        prepend variantSets = "knob"
                        variants = {
                            string knob = "round"
                        }
                    )
                    {
                        variantSet "knob" = {
                            "round" {
                                def Sphere "Knob"
                                {
                                }
                            }
                            "square" {
                                def Cube "Knob"
                                {
                                }
                            }
                        }
                    }
                }
            }
        }

        def Sphere "Ball" (
            prepend inherits = </_shaded>
            variants = {
                string shade = "gloss"
            }
        )
        {
        }
    ''')
    expected(d, "through_arcs", values=["/Shelf.tint", "/Ball.roughness"])


def compose_around():
    d = os.path.join(ROOT, "compose_around")
    # A camera, a light and a material every case can use.
    write(d, "present.usda", '''
        #usda 1.0
        (
            defaultPrim = "World"
        )

        def Xform "World"
        {
            def Camera "Cam"
            {
                double3 xformOp:translate = (0, 0, 6)
                uniform token[] xformOpOrder = ["xformOp:translate"]
            }

            def DomeLight "Sky"
            {
                float inputs:intensity = 1
            }

            def Sphere "Ball"
            {
            }
        }

        def Scope "Looks"
        {
            def Material "Red"
            {
                token outputs:surface.connect = </Looks/Red/Surface.outputs:surface>

                def Shader "Surface"
                {
                    uniform token info:id = "UsdPreviewSurface"
                    color3f inputs:diffuseColor = (0.8, 0.1, 0.1)
                    token outputs:surface
                }
            }
        }
    ''')
    write(d, "missing_sublayer.usda", '''
        #usda 1.0
        (
            subLayers = [
                @./gone_sublayer.usda@,
                @./present.usda@
            ]
        )

        over "World"
        {
            def Cube "Box"
            {
            }
        }
    ''')
    expected(d, "missing_sublayer",
             warnings=["cannot read layer `./gone_sublayer.usda`"])

    write(d, "missing_reference.usda", '''
        #usda 1.0
        (
            subLayers = [
                @./present.usda@
            ]
        )

        over "World"
        {
            def Xform "Prop" (
                prepend references = @./gone_prop.usda@
            )
            {
                def Cube "Local"
                {
                }
            }

            def Xform "Heavy" (
                prepend payload = @./gone_payload.usda@</Heavy>
            )
            {
            }
        }
    ''')
    expected(d, "missing_reference",
             warnings=["cannot read layer `./gone_prop.usda`", "`./gone_payload.usda`"])

    write(d, "asset.usda", '''
        #usda 1.0
        (
            defaultPrim = "Asset"
        )

        def Xform "Asset"
        {
            def Sphere "Part"
            {
            }
        }
    ''')
    write(d, "no_default.usda", '''
        #usda 1.0

        def Xform "Asset"
        {
        }
    ''')
    write(d, "missing_prim.usda", '''
        #usda 1.0
        (
            subLayers = [
                @./present.usda@
            ]
        )

        over "World"
        {
            def Xform "Good" (
                prepend references = @./asset.usda@
            )
            {
            }

            def Xform "External" (
                prepend references = @./asset.usda@</Nope>
            )
            {
                def Cube "Local"
                {
                }
            }

            def Xform "Internal" (
                prepend references = </Nowhere>
            )
            {
            }

            def Xform "Loaded" (
                prepend payload = @./asset.usda@</AlsoNope>
            )
            {
            }

            def Xform "NoDefault" (
                prepend references = @./no_default.usda@
            )
            {
            }
        }
    ''')
    expected(d, "missing_prim",
             warnings=["the prim `/Nope` that this reference targets does not exist", "2 more like it",
                       "`./no_default.usda` has no `defaultPrim`"])

    write(d, "binding_missing.usda", '''
        #usda 1.0
        (
            subLayers = [
                @./present.usda@
            ]
        )

        over "World" (
            prepend apiSchemas = ["MaterialBindingAPI"]
        )
        {
            rel material:binding = </Looks/Red>

            def Sphere "Unbound" (
                prepend apiSchemas = ["MaterialBindingAPI"]
            )
            {
                rel material:binding = </Looks/Missing>
                double3 xformOp:translate = (2, 0, 0)
                uniform token[] xformOpOrder = ["xformOp:translate"]
            }

            def Sphere "Inherits"
            {
                double3 xformOp:translate = (-2, 0, 0)
                uniform token[] xformOpOrder = ["xformOp:translate"]
            }

            def Sphere "Slotted"
            {
                rel material:slotBinding:_010 = </Looks/AlsoMissing>
                double3 xformOp:translate = (0, 2, 0)
                uniform token[] xformOpOrder = ["xformOp:translate"]
            }
        }
    ''')
    expected(d, "binding_missing", bindings=True,
             warnings=["`material:binding` on `/World/Unbound` targets `/Looks/Missing`, which does not exist",
                       "slot binding `material:slotBinding:_010` on `/World/Slotted` targets `/Looks/AlsoMissing`"])

    write(d, "X_mat.mtlx", '''
        <?xml version="1.0"?>
        <materialx version="1.38">
          <standard_surface name="SR_red" type="surfaceshader">
            <input name="base_color" type="color3" value="0.8, 0.1, 0.1" />
          </standard_surface>
          <surfacematerial name="Red" type="material">
            <input name="surfaceshader" type="surfaceshader" nodename="SR_red" />
          </surfacematerial>
        </materialx>
    ''')
    write(d, "materialx.usda", '''
        #usda 1.0
        (
            subLayers = [
                @./present.usda@
            ]
        )

        over "World"
        {
            def Scope "Materials" (
                prepend references = @./X_mat.mtlx@</MaterialX/Materials>
            )
            {
            }

            over "Ball" (
                prepend apiSchemas = ["MaterialBindingAPI"]
            )
            {
                rel material:binding = </World/Materials/Red>
            }
        }
    ''')
    # usd-core without usdMtlx composes /World/Materials empty: not an oracle for strata,
    # which reads the document (tests/mtlx/, `a_referenced_document_binds_like_usd`).

    write(d, "broken.usda", '''
        #usda 1.0
        (
            defaultPrim = "Broken"
        )

        def Xform "Broken"
        {
            double x = (1, 2
        }
    ''')
    write(d, "malformed.usda", '''
        #usda 1.0
        (
            subLayers = [
                @./present.usda@
            ]
        )

        over "World"
        {
            def Xform "FromBroken" (
                prepend references = @./broken.usda@
            )
            {
                def Cube "Local"
                {
                }
            }
        }
    ''')
    expected(d, "malformed", warnings=["layer `./broken.usda` is not valid USD"])


if __name__ == "__main__":
    variants()
    variants_through_arcs()
    compose_around()
