#!/usr/bin/env python3
"""Runs the MaterialX project's public documents through `strata check` and prints a table.

The documents are MaterialX's `resources/Materials/TestSuite/{stdlib,pbrlib}` and
`resources/Materials/Examples` (Apache-2.0; not vendored: pass a checkout with --materialx, or
the script clones one, `resources/` only, into target/materialx). For each document:

- its `surfacematerial`s are bound to one sphere each in a generated USD scene
  (`@doc.mtlx@</MaterialX/Materials/NAME>`, as USD's MaterialX plugin names them);
- a document with node graphs but no material (most of stdlib's) is wrapped as MaterialX's
  own render tests do: each graph output of a type strata reads (and each top-level output of
  a node) becomes the emission of a `surface` (`uniform_edf` of the output, converted to
  color3), each graph's surface shader output the surface of a material, one material per
  output, in a copy of the document written beside it;

then `strata check SCENE` runs once per document. Counted: documents, materials checked,
documents that check clean, with warnings, with errors (a diagnostic, exit 1), and crashes
(any other exit status: a panic is a bug). The most common warnings are listed by kind.

    python3 tools/mtlx_test_suite.py [--materialx DIR] [--strata BIN] [--markdown]
"""

import argparse
import collections
import os
import re
import subprocess
import sys
import tempfile
import xml.etree.ElementTree as ET

SETS = ["TestSuite/stdlib", "TestSuite/pbrlib", "Examples"]
REPO = "https://github.com/AcademySoftwareFoundation/MaterialX"
# Output types a `convert` to color3 reads (strata's float, triple and 4-channel variants).
CONVERTIBLE = {"float", "color3", "vector3", "vector2", "color4", "vector4"}


def locate(materialx):
    """The `resources/Materials` directory of a MaterialX checkout, cloned when absent."""
    if materialx is None:
        materialx = os.path.join("target", "materialx")
        if not os.path.isdir(os.path.join(materialx, "resources")):
            subprocess.run(["git", "clone", "--depth", "1", "--filter=blob:none", "--sparse", REPO, materialx], check=True)
            subprocess.run(["git", "-C", materialx, "sparse-checkout", "set", "resources/Materials", "resources/Images"], check=True)
    root = os.path.join(materialx, "resources", "Materials")
    if not os.path.isdir(root):
        sys.exit(f"no resources/Materials under {materialx}")
    return root


def materials_of(root):
    """The Materials strata's translation makes of a document (src/scene/mtlx.rs): its
    top-level surface materials (and instances of material nodes the document defines), and
    each node graph output of type material (named after the graph, `graph_output` when the
    graph has several)."""
    names = [m.get("name") for m in root if m.get("type") == "material" and m.tag not in ("volumematerial", "output")]
    for graph in root.findall("nodegraph"):
        if graph.get("nodedef"):
            continue
        outputs = [o for o in graph.findall("output") if o.get("type") == "material"]
        for out in outputs:
            names.append(graph.get("name") if len(outputs) == 1 else f"{graph.get('name')}_{out.get('name')}")
    return names


def wrap_outputs(path, tree):
    """A copy of the document beside it with a material per convertible node-graph output;
    its path and the material names, or (None, []) when it has none."""
    root = tree.getroot()
    names = []
    # Graph outputs (not of graphs that implement a node definition) and the document's
    # top-level outputs (of nodes).
    outputs = [(g, o) for g in root.findall("nodegraph") if not g.get("nodedef") for o in g.findall("output")]
    outputs += [(None, o) for o in root.findall("output") if o.get("nodename")]
    for graph, out in outputs:
        kind = out.get("type")
        if kind == "surfaceshader" and graph is not None:
            # A graph's surface shader output is a material's surface (pbrlib's BSDF tests).
            tag = f"{graph.get('name')}_{out.get('name')}"
            material = ET.SubElement(root, "surfacematerial", name=f"strata_m_{tag}", type="material")
            ET.SubElement(
                material, "input", name="surfaceshader", type="surfaceshader", nodegraph=graph.get("name"), output=out.get("name")
            )
            names.append(f"strata_m_{tag}")
            continue
        if kind not in CONVERTIBLE:
            continue
        tag = f"{graph.get('name')}_{out.get('name')}" if graph is not None else f"top_{out.get('name')}"
        convert = ET.SubElement(root, "convert", name=f"strata_c_{tag}", type="color3")
        if graph is not None:
            ET.SubElement(convert, "input", name="in", type=kind, nodegraph=graph.get("name"), output=out.get("name"))
        else:
            ET.SubElement(convert, "input", name="in", type=kind, nodename=out.get("nodename"))
        edf = ET.SubElement(root, "uniform_edf", name=f"strata_e_{tag}", type="EDF")
        ET.SubElement(edf, "input", name="color", type="color3", nodename=f"strata_c_{tag}")
        surface = ET.SubElement(root, "surface", name=f"strata_s_{tag}", type="surfaceshader")
        ET.SubElement(surface, "input", name="edf", type="EDF", nodename=f"strata_e_{tag}")
        material = ET.SubElement(root, "surfacematerial", name=f"strata_m_{tag}", type="material")
        ET.SubElement(material, "input", name="surfaceshader", type="surfaceshader", nodename=f"strata_s_{tag}")
        names.append(f"strata_m_{tag}")
    if not names:
        return None, []
    wrapped = path[: -len(".mtlx")] + ".strata_wrapped.mtlx"
    tree.write(wrapped)
    return wrapped, names


def scene_for(path, materials):
    """USDA text binding one sphere to each material of the document at `path`."""
    lines = ["#usda 1.0"]
    for k, name in enumerate(materials):
        lines.append(
            f'def Sphere "Ball{k}" (prepend apiSchemas = ["MaterialBindingAPI"]) '
            f"{{ rel material:binding = </M{k}>\n    double3 xformOp:translate = ({3 * k}, 0, 0)\n"
            f'    uniform token[] xformOpOrder = ["xformOp:translate"] }}'
        )
        lines.append(f'def Material "M{k}" (prepend references = @{path}@</MaterialX/Materials/{name}>) {{}}')
    return "\n".join(lines) + "\n"


def warning_kind(line):
    """A warning's message with names and numbers blanked, for counting kinds."""
    message = line.split("warning:", 1)[1].strip()
    return re.sub(r"`[^`]*`", "`…`", message)


def check(strata, path):
    """(materials checked, warnings, errors, crashed, warning kinds) of one document."""
    try:
        tree = ET.parse(path)
    except ET.ParseError:
        tree = None
    materials = [] if tree is None else materials_of(tree.getroot())
    target = path
    if tree is not None and not materials:
        wrapped, materials = wrap_outputs(path, tree)
        target = wrapped or path
    with tempfile.TemporaryDirectory() as tmp:
        scene = os.path.join(tmp, "scene.usda")
        with open(scene, "w") as f:
            if materials:
                f.write(scene_for(os.path.abspath(target), materials))
            else:
                # Nothing to bind: the document is read as a sublayer (parsing and translation).
                f.write(f"#usda 1.0\n(\n    subLayers = [@{os.path.abspath(path)}@]\n)\n")
        run = subprocess.run([strata, "check", scene], capture_output=True, text=True, timeout=600)
    text = run.stdout + run.stderr
    warnings = [warning_kind(l) for l in text.splitlines() if "warning:" in l]
    errors = sum(1 for l in text.splitlines() if re.match(r"^\s*error", l) or ": error" in l)
    crashed = run.returncode not in (0, 1)
    if run.returncode == 1 and errors == 0:
        errors = 1
    return len(materials), warnings, errors, crashed, text


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--materialx", help="a MaterialX checkout (default: clone into target/materialx)")
    parser.add_argument("--strata", default=os.path.join(os.environ.get("CARGO_TARGET_DIR", "target"), "release", "strata"))
    parser.add_argument("--markdown", action="store_true", help="print the tables as Markdown")
    parser.add_argument("--verbose", action="store_true", help="print each document's diagnostics")
    args = parser.parse_args()
    root = locate(args.materialx)
    kinds = collections.Counter()
    rows = []
    crashes = []
    for subset in SETS:
        docs = sorted(
            os.path.join(d, f)
            for d, _, files in os.walk(os.path.join(root, subset))
            for f in files
            if f.endswith(".mtlx") and not f.endswith(".strata_wrapped.mtlx")
        )
        row = collections.Counter(documents=len(docs))
        for doc in docs:
            n, warnings, errors, crashed, text = check(args.strata, doc)
            row["materials"] += n
            row["clean"] += not warnings and not errors and not crashed
            row["warned"] += bool(warnings) and not errors and not crashed
            row["errors"] += bool(errors) and not crashed
            row["crashed"] += crashed
            kinds.update(set(warnings))
            if crashed:
                crashes.append(doc)
            if args.verbose:
                print(f"== {os.path.relpath(doc, root)}: {n} materials\n{text}")
        rows.append((subset, row))
    columns = ["documents", "materials", "clean", "warned", "errors", "crashed"]
    if args.markdown:
        print("| set | " + " | ".join(columns) + " |")
        print("|---|" + "---|" * len(columns))
        for subset, row in rows:
            print(f"| {subset} | " + " | ".join(str(row[c]) for c in columns) + " |")
        print("\n| documents | warning |\n|---|---|")
        for kind, n in kinds.most_common(25):
            print(f"| {n} | {kind} |")
    else:
        print(f"{'set':18}" + "".join(f"{c:>11}" for c in columns))
        for subset, row in rows:
            print(f"{subset:18}" + "".join(f"{row[c]:>11}" for c in columns))
        print("\nmost common warnings (documents):")
        for kind, n in kinds.most_common(25):
            print(f"{n:5}  {kind}")
    for doc in crashes:
        print(f"CRASHED: {doc}")
    return 1 if crashes else 0


if __name__ == "__main__":
    sys.exit(main())
