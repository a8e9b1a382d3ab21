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

Run from the repository root: python3 tools/make_slot_collection_fixtures.py
"""
import os

from pxr import Sdf, Usd, UsdGeom, UsdShade

FOLDER = os.path.join("tests", "fixtures", "slot_collections")

# Mesh prims of every case (parents are Xforms unless listed as meshes themselves).
MESHES = ["/W/a", "/W/a/x", "/W/a/x/y", "/W/a/z", "/W/b", "/W/b/c", "/Other/m"]


def stage_with_meshes():
    stage = Usd.Stage.CreateInMemory()
    for path in ["/W", "/Other", "/Sets"]:
        UsdGeom.Xform.Define(stage, path)
    for path in MESHES:
        UsdGeom.Mesh.Define(stage, path)
    UsdShade.Material.Define(stage, "/M/Dirt")
    return stage


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
    rel = stage.GetPrimAtPath(binding_prim).CreateRelationship("material:slotBinding:_050:collection:dirt")
    rel.SetTargets([Sdf.Path(f"{owner}.collection:{collection}"), Sdf.Path("/M/Dirt")])
    os.makedirs(FOLDER, exist_ok=True)
    stage.GetRootLayer().Export(os.path.join(FOLDER, name + ".usda"))

    query = api.ComputeMembershipQuery()
    lines = [f"# {name}.usda: membership by usd-core {'.'.join(map(str, Usd.GetVersion()))}"]
    for path in MESHES:
        under = path == binding_prim or path.startswith(binding_prim + "/")
        member = query.IsPathIncluded(Sdf.Path(path))
        lines.append(f"bound {path} {'yes' if under and member else 'no'}")
    with open(os.path.join(FOLDER, name + ".expected"), "w") as f:
        f.write("\n".join(lines) + "\n")


case("expand", "/W", "/W", "dirty", includes=["/W/a"], excludes=["/W/a/x"])
case("explicit_only", "/W", "/W", "dirty", includes=["/W/a", "/W/a/x/y"], rule="explicitOnly")
case("include_root", "/W", "/W/a", "everything", excludes=["/W/a/z"], include_root=True)
case("closest_decides", "/W", "/W", "dirty", includes=["/W", "/W/a/x"], excludes=["/W/a"])
case("other_owner", "/Sets", "/W", "dirty", includes=["/W/b", "/Other"])
case("prims_and_props", "/W", "/W", "dirty", includes=["/W/b"], rule="expandPrimsAndProperties")
