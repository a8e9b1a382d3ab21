#!/usr/bin/env python3
"""Writes the membership fixtures of tests/slot_rules.rs: stages with collection-based slot
bindings (DESIGN.md rule 1c) and, for each, the membership Pixar's USD library computes
(`pip install usd-core`; `Usd.CollectionAPI.ComputeMembershipQuery`), so strata's
UsdCollectionAPI reading is checked against USD, never against itself.

tests/fixtures/slot_collections/CASE.usda      the stage (written by usd-core)
tests/fixtures/slot_collections/CASE.expected  one line per renderable prim:

    bound PATH yes|no    whether slot `050` is bound there by the collection binding: the prim
                         is the binding prim or below it, and usd-core's membership query
                         includes it

Cases:
  expand          includes with an exclude below them (expandPrims)
  explicit_only   expansionRule explicitOnly: the named paths and nothing below
  include_root    includeRoot with an exclude; the binding prim limits the reach
  closest_decides include, exclude below it, include again below that
  other_owner     the collection lives on another prim and names prims outside the
                  binding prim, which it does not reach
  prims_and_props expansionRule expandPrimsAndProperties (prims as expandPrims)

Membership expressions (USD path expressions; `expr_*`, on a stage with kinds, a Sphere, an
applied API and a variant selection added). Their .expected files also hold

    collection OWNER NAME   the bound collection
    member PATH             each path `Usd.ComputeIncludedPathsFromCollection` returns, so
                            every prim of the stage is checked, not only the renderable ones

  expr_glob        `//` and a name glob
  expr_operators   difference, intersection and union in one expression (precedence)
  expr_complement  complement, grouping, implied union, `isa` and `abstract`
  expr_predicates  `model`, `group`, `not`, `isa`, `hasAPI`, `kind` with `strict`
  expr_relative    relative patterns and `..`, made absolute at the collection's prim
  expr_reference   `%/W:base`: another collection's expression (its includes play no part)
  expr_weaker      `%_`: a sublayer's weaker expression (layers/expr_weaker_base.usda)
  expr_variant     `variant(look=dirt*)`
  expr_ignored     includes authored: the expression is not used

Run from the repository root: python3 tools/make_slot_collection_fixtures.py
"""
import os

from pxr import Sdf, Usd, UsdGeom, UsdShade

FOLDER = os.path.join("tests", "fixtures", "slot_collections")

# Mesh prims of every case (parents are Xforms unless listed as meshes themselves).
MESHES = ["/W/a", "/W/a/x", "/W/a/x/y", "/W/a/z", "/W/b", "/W/b/c", "/Other/m"]


# Renderable prims the expression cases add.
EXTRA_GPRIMS = ["/W/b/Ball1", "/W/b/Balloon", "/W/a/x/Ball2"]


def stage_with_meshes(stage=None):
    stage = stage or Usd.Stage.CreateInMemory()
    for path in ["/W", "/Other", "/Sets"]:
        UsdGeom.Xform.Define(stage, path)
    for path in MESHES:
        UsdGeom.Mesh.Define(stage, path)
    UsdShade.Material.Define(stage, "/M/Dirt")
    return stage


def with_expression_extras(stage):
    """Kinds (/W an assembly, /W/a a component, /W/b a subcomponent), a Sphere, two more
    Meshes, MaterialBindingAPI on /W/b/c and a variant selection on /W/b."""
    Usd.ModelAPI(stage.GetPrimAtPath("/W")).SetKind("assembly")
    Usd.ModelAPI(stage.GetPrimAtPath("/W/a")).SetKind("component")
    Usd.ModelAPI(stage.GetPrimAtPath("/W/b")).SetKind("subcomponent")
    UsdGeom.Mesh.Define(stage, "/W/b/Ball1")
    UsdGeom.Mesh.Define(stage, "/W/b/Balloon")
    UsdGeom.Sphere.Define(stage, "/W/a/x/Ball2")
    UsdShade.MaterialBindingAPI.Apply(stage.GetPrimAtPath("/W/b/c"))
    looks = stage.GetPrimAtPath("/W/b").GetVariantSets().AddVariantSet("look")
    looks.AddVariant("dirty")
    looks.AddVariant("clean")
    looks.SetVariantSelection("dirty")
    return stage


def write_expected(name, stage, api, binding_prim, renderable):
    query = api.ComputeMembershipQuery()
    lines = [f"# {name}.usda: membership by usd-core {'.'.join(map(str, Usd.GetVersion()))}"]
    for path in renderable:
        under = path == binding_prim or path.startswith(binding_prim + "/")
        member = query.IsPathIncluded(Sdf.Path(path))
        lines.append(f"bound {path} {'yes' if under and member else 'no'}")
    if renderable != MESHES:
        lines.append(f"collection {api.GetPrim().GetPath()} {api.GetName()}")
        for path in Usd.ComputeIncludedPathsFromCollection(query, stage):
            lines.append(f"member {path}")
    with open(os.path.join(FOLDER, name + ".expected"), "w") as f:
        f.write("\n".join(lines) + "\n")


def bind(stage, binding_prim, owner, collection):
    rel = stage.GetPrimAtPath(binding_prim).CreateRelationship("material:slotBinding:_050:collection:dirt")
    rel.SetTargets([Sdf.Path(f"{owner}.collection:{collection}"), Sdf.Path("/M/Dirt")])


def expression_case(name, expression, owner="/W", binding_prim="/W", setup=None):
    stage = with_expression_extras(stage_with_meshes())
    api = Usd.CollectionAPI.Apply(stage.GetPrimAtPath(owner), "dirty")
    api.CreateMembershipExpressionAttr(Sdf.PathExpression(expression))
    if setup:
        setup(stage, api)
    bind(stage, binding_prim, owner, "dirty")
    os.makedirs(FOLDER, exist_ok=True)
    stage.GetRootLayer().Export(os.path.join(FOLDER, name + ".usda"))
    write_expected(name, stage, api, binding_prim, MESHES + EXTRA_GPRIMS)


def weaker_expression_case():
    """`%_` composes over the sublayer's expression: the stage is a root layer with a
    stronger expression over a sublayer that authors the weaker one."""
    os.makedirs(os.path.join(FOLDER, "layers"), exist_ok=True)
    base_path = os.path.join(FOLDER, "layers", "expr_weaker_base.usda")
    base = with_expression_extras(stage_with_meshes())
    api = Usd.CollectionAPI.Apply(base.GetPrimAtPath("/W"), "dirty")
    api.CreateMembershipExpressionAttr(Sdf.PathExpression("/W/b// - /W/b/c"))
    base.GetRootLayer().Export(base_path)
    root = Sdf.Layer.CreateAnonymous(".usda")
    root.subLayerPaths.append("layers/expr_weaker_base.usda")
    root_path = os.path.join(FOLDER, "expr_weaker.usda")
    root.Export(root_path)
    stage = Usd.Stage.Open(root_path)
    api = Usd.CollectionAPI(stage.GetPrimAtPath("/W"), "dirty")
    api.GetMembershipExpressionAttr().Set(Sdf.PathExpression("%_ /W/a/z"))
    bind(stage, "/W", "/W", "dirty")
    stage.GetRootLayer().Save()
    write_expected("expr_weaker", stage, api, "/W", MESHES + EXTRA_GPRIMS)


def case(name, owner, binding_prim, collection, includes=(), excludes=(), rule=None, include_root=False):
    stage = stage_with_meshes()
    api = Usd.CollectionAPI.Apply(stage.GetPrimAtPath(owner), collection)
    for p in includes:
        api.CreateIncludesRel().AddTarget(p)
    for p in excludes:
        api.CreateExcludesRel().AddTarget(p)
    if rule:
        api.CreateExpansionRuleAttr(rule)
    if include_root:
        api.CreateIncludeRootAttr(True)
    bind(stage, binding_prim, owner, collection)
    os.makedirs(FOLDER, exist_ok=True)
    stage.GetRootLayer().Export(os.path.join(FOLDER, name + ".usda"))
    write_expected(name, stage, api, binding_prim, MESHES)


case("expand", "/W", "/W", "dirty", includes=["/W/a"], excludes=["/W/a/x"])
case("explicit_only", "/W", "/W", "dirty", includes=["/W/a", "/W/a/x/y"], rule="explicitOnly")
case("include_root", "/W", "/W/a", "everything", excludes=["/W/a/z"], include_root=True)
case("closest_decides", "/W", "/W", "dirty", includes=["/W", "/W/a/x"], excludes=["/W/a"])
case("other_owner", "/Sets", "/W", "dirty", includes=["/W/b", "/Other"])
case("prims_and_props", "/W", "/W", "dirty", includes=["/W/b"], rule="expandPrimsAndProperties")

expression_case("expr_glob", "/W//Ball*")
expression_case("expr_operators", "/W/a// - /W/a/x & /W/a/x// + /W/b/*")
expression_case("expr_complement", "~(/W/b// /Other//) & //{isa:Gprim and abstract:false}")
expression_case(
    "expr_predicates",
    "(/W/{model and not group}// - //{isa:Sphere}) /W/b/*{hasAPI:MaterialBindingAPI} //{kind(component, strict=true)}",
)
expression_case("expr_relative", "a/x// ../Other/*")


def base_collection(stage, _api):
    # A reference stands for the other collection's expression; its includes play no part.
    base = Usd.CollectionAPI.Apply(stage.GetPrimAtPath("/W"), "base")
    base.CreateIncludesRel().AddTarget("/W/b")
    base.CreateMembershipExpressionAttr(Sdf.PathExpression("a//"))


expression_case("expr_reference", "%/W:base - /W/a/x", owner="/Sets", setup=base_collection)
weaker_expression_case()
expression_case("expr_variant", "//{variant(look=dirt*)}//")
expression_case(
    "expr_ignored", "/W/a//", setup=lambda _stage, api: api.CreateIncludesRel().AddTarget("/W/b")
)
