//! MaterialX documents (`.mtlx`) as USD layers, translated as USD's own MaterialX file-format
//! plugin (usdMtlx) does, into USDA text that the usda parser then reads like any layer:
//!
//! - every material (`<surfacematerial>`, any node of type `material`) becomes
//!   `/MaterialX/Materials/<name>`, a `Material` whose `outputs:mtlx:surface` (and
//!   `outputs:mtlx:displacement`) connects to its shader; the surface shader's authored values
//!   are promoted to the Material's interface inputs (`inputs:base_color` on the Material,
//!   connected from the shader), so a USD layer above can override them;
//! - every node becomes a `Shader` whose `info:id` is its node definition (`ND_image_color3`,
//!   `ND_standard_surface_surfaceshader`, the `nodedef` attribute when authored); the nodes
//!   and node graphs a material uses are copied under it, so a reference to
//!   `</MaterialX/Materials/M>` carries its whole network;
//! - every `<nodegraph>` becomes `/MaterialX/NodeGraphs/<name>`, a `NodeGraph` with its
//!   interface inputs and outputs (and, beyond usdMtlx, copies of the top-level nodes its
//!   interface inputs read, so a reference to the graph keeps those connections);
//! - `nodename`/`output`, `nodegraph`/`output` and `interfacename` become `.connect`s;
//!   `colorspace` (inherited from the enclosing elements) becomes the `colorSpace` metadata of
//!   colour and filename inputs; `fileprefix` is prefixed to filename values; inputs bound to a
//!   `geomprop`/`defaultgeomprop` keep the node's default (the node library reads the geometric
//!   property itself).
//!
//! The XML is read with roxmltree, which keeps every node's byte range: a malformed document
//! is reported at its line and column, and what the translation leaves out is a warning at the
//! XML element that authored it.

use std::collections::{BTreeSet, HashMap, HashSet};
use std::fmt::Write as _;
use std::ops::Range;

mod upgrade;

use upgrade::{FILM_INPUTS, ThinFilmUpgrade};

/// Something to report about a document, at a byte range of its XML text.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Problem {
    /// Where in the XML.
    pub range: Range<usize>,
    /// What is wrong.
    pub message: String,
}

/// A translated document: USDA text and what the translation could not carry.
#[derive(Debug)]
pub struct Translation {
    /// The layer, as USDA text.
    pub usda: String,
    /// Warnings, located in the XML.
    pub warnings: Vec<Problem>,
}

/// Elements that define or organise, not shade: they translate to nothing.
const NON_NODES: &[&str] = &[
    "nodedef",
    "implementation",
    "typedef",
    "unittypedef",
    "unitdef",
    "targetdef",
    "geompropdef",
    "attributedef",
    "look",
    "lookgroup",
    "materialassign",
    "visibility",
    "collection",
    "geominfo",
    "propertyset",
    "propertysetassign",
    "variant",
    "variantset",
    "variantassign",
    "backdrop",
    "comment",
    "output",
    "input",
    "token",
];

/// Translates a MaterialX document. `Err` when the text is not well-formed XML or not a
/// MaterialX document (its root is not `<materialx>`).
pub fn translate(xml: &str) -> Result<Translation, Problem> {
    let options = roxmltree::ParsingOptions { allow_dtd: false, ..Default::default() };
    let doc = roxmltree::Document::parse_with_options(xml, options).map_err(|e| {
        let at = offset_of(xml, e.pos().row as usize, e.pos().col as usize);
        Problem { range: at..at, message: format!("malformed MaterialX document: {e}") }
    })?;
    let root = doc.root_element();
    if root.tag_name().name() != "materialx" {
        return Err(Problem {
            range: tag_range(root),
            message: format!(
                "not a MaterialX document: the root element is `<{}>`, not `<materialx>`",
                root.tag_name().name()
            ),
        });
    }
    let mut warnings = Vec::new();
    let films = ThinFilmUpgrade::scan(root, &mut warnings);
    let mut t = Translator { warnings, top: HashMap::new(), outputs: HashMap::new(), defs: HashMap::new(), films };
    for child in root.children().filter(|c| c.is_element()) {
        if let Some(name) = child.attribute("name") {
            t.top.insert(name.to_string(), child);
        }
    }
    t.collect_definitions(root);
    t.collect_outputs(root);
    let mut out = String::from("#usda 1.0\n\ndef \"MaterialX\"\n{\n    def \"Materials\"\n    {\n");
    let mut seen = HashSet::new();
    for child in root.children().filter(|c| c.is_element()) {
        let Some(name) = child.attribute("name") else { continue };
        if child.attribute("type") == Some("material") && seen.insert(identifier(name)) {
            t.material(&mut out, name, child, Place::TOP);
        }
    }
    // A graph whose output is a material (MaterialX renders it as one): a Material named
    // after the graph (`<graph>_<output>` when it has several).
    for graph in root.children().filter(|c| is_graph(*c) && c.attribute("nodedef").is_none()) {
        let Some(graph_name) = graph.attribute("name") else { continue };
        let materials: Vec<Node> = graph
            .children()
            .filter(|o| o.is_element() && o.tag_name().name() == "output" && o.attribute("type") == Some("material"))
            .collect();
        for output in &materials {
            let Some(node) = output.attribute("nodename").and_then(|n| child_named(graph, n)) else { continue };
            let name = match materials.len() {
                1 => graph_name.to_string(),
                _ => format!("{graph_name}_{}", output.attribute("name").unwrap_or("out")),
            };
            if seen.insert(identifier(&name)) {
                t.material(&mut out, &name, node, Place { graph: Some(graph), instance: None });
            }
        }
    }
    out.push_str("    }\n\n    def \"NodeGraphs\"\n    {\n");
    // Graphs that implement a node definition are definitions: their instances carry them.
    for child in root.children().filter(|c| is_graph(*c) && c.attribute("nodedef").is_none()) {
        let Some(name) = child.attribute("name") else { continue };
        t.node_graph(&mut out, child, &format!("/MaterialX/NodeGraphs/{}", identifier(name)), 2, None, None);
    }
    out.push_str("    }\n}\n");
    for child in root.children().filter(|c| c.is_element()) {
        let tag = child.tag_name().name();
        if child.attribute("name").is_none() && !NON_NODES.contains(&tag) {
            t.warn(child, format!("`<{tag}>` has no `name`; it is ignored"));
        }
    }
    // A library graph and the materials using it reach the same elements: report each once.
    let mut reported = HashSet::new();
    t.warnings.retain(|w| reported.insert((w.range.start, w.message.clone())));
    Ok(Translation { usda: out, warnings: t.warnings })
}

type Node<'a, 'i> = roxmltree::Node<'a, 'i>;

/// A shader, where it lives, and the prims holding it under its material, outermost first.
type Located<'a, 'i> = (Node<'a, 'i>, Place<'a, 'i>, Vec<Node<'a, 'i>>);

/// The node that `graph`'s output `output` (else its first output) reads.
fn graph_output<'a, 'i>(graph: Node<'a, 'i>, output: Option<&str>) -> Option<Node<'a, 'i>> {
    let mut outputs = graph.children().filter(|c| c.is_element() && c.tag_name().name() == "output");
    let found = outputs.find(|o| output.is_none() || o.attribute("name") == output)?;
    child_named(graph, found.attribute("nodename")?)
}

/// Where a node lives: at the document's top level or inside a node graph; a graph that
/// implements one of the document's own node definitions is written once per `instance` of
/// that node.
#[derive(Clone, Copy)]
struct Place<'a, 'i> {
    graph: Option<Node<'a, 'i>>,
    instance: Option<Node<'a, 'i>>,
}

impl Place<'_, '_> {
    const TOP: Self = Place { graph: None, instance: None };
}

fn is_graph(node: Node) -> bool {
    node.is_element() && node.tag_name().name() == "nodegraph"
}

/// The node that reads geometric property `name` (MaterialX's standard `geompropdef`s), as a
/// node definition id and its `space` input.
fn geomprop_node(name: &str) -> Option<(&'static str, Option<&'static str>)> {
    Some(match name {
        "UV0" => ("ND_texcoord_vector2", None),
        "Nworld" => ("ND_normal_vector3", None),
        "Nobject" => ("ND_normal_vector3", Some("object")),
        "Pworld" => ("ND_position_vector3", None),
        "Pobject" => ("ND_position_vector3", Some("object")),
        "Tworld" => ("ND_tangent_vector3", None),
        "Tobject" => ("ND_tangent_vector3", Some("object")),
        "Bworld" => ("ND_bitangent_vector3", None),
        "Bobject" => ("ND_bitangent_vector3", Some("object")),
        _ => return None,
    })
}

struct Translator<'a, 'i> {
    warnings: Vec<Problem>,
    /// The document's top-level elements by name.
    top: HashMap<String, Node<'a, 'i>>,
    /// Outputs other elements connect to, per producing element (by its node id): its
    /// `outputs:` to declare, with their MaterialX types.
    outputs: HashMap<roxmltree::NodeId, Vec<(String, String)>>,
    /// The document's own node definitions that a node graph implements, by node category:
    /// (`<nodedef>`, `<nodegraph nodedef=...>`).
    defs: HashMap<String, Vec<(Node<'a, 'i>, Node<'a, 'i>)>>,
    /// 1.38's thin-film layers, rewritten as MaterialX's upgrade to 1.39 does.
    films: ThinFilmUpgrade<'a, 'i>,
}

impl<'a, 'i> Translator<'a, 'i> {
    fn warn(&mut self, at: Node, message: String) {
        self.warnings.push(Problem { range: tag_range(at), message });
    }

    /// Records the node definitions the document implements with its own node graphs.
    fn collect_definitions(&mut self, root: Node<'a, 'i>) {
        for graph in root.children().filter(|c| is_graph(*c)) {
            let Some(def_name) = graph.attribute("nodedef") else { continue };
            let def = root
                .children()
                .find(|c| c.is_element() && c.tag_name().name() == "nodedef" && c.attribute("name") == Some(def_name));
            match def.and_then(|d| d.attribute("node").map(|category| (d, category))) {
                Some((def, category)) => self.defs.entry(category.to_string()).or_default().push((def, graph)),
                None => self.warn(
                    graph,
                    format!("the graph implements `{def_name}`, which the document does not define; it is ignored"),
                ),
            }
        }
    }

    /// The document's definition of `node` and the graph implementing it, if the document
    /// defines its category: the version the node asks for (else the default version), of the
    /// node's type.
    fn implementation(&self, node: Node<'a, 'i>) -> Option<(Node<'a, 'i>, Node<'a, 'i>)> {
        let candidates = self.defs.get(node.tag_name().name())?;
        let version_fits = |def: &Node| match node.attribute("version") {
            Some(v) => def.attribute("version") == Some(v),
            None => def.attribute("isdefaultversion") == Some("true") || candidates.len() == 1,
        };
        let type_fits = |def: &Node| {
            let ty = node.attribute("type");
            ty == Some("multioutput")
                || def.children().any(|o| o.tag_name().name() == "output" && o.attribute("type") == ty)
        };
        let pick = |fits: &dyn Fn(&Node) -> bool| candidates.iter().find(|(d, _)| fits(d)).copied();
        pick(&|d| version_fits(d) && type_fits(d)).or_else(|| pick(&type_fits)).or_else(|| candidates.first().copied())
    }

    /// The shader node a material input reads, where it lives, and the prims that hold it
    /// under the material (graphs and document-defined nodes, outermost first): through
    /// `nodename` (a node, or the shader inside a document-defined node's graph),
    /// `nodegraph`/`output` (the shader inside a graph) and `interfacename` (the enclosing
    /// graph's input).
    fn shader_of(&self, input: Node<'a, 'i>, place: Place<'a, 'i>, depth: usize) -> Option<Located<'a, 'i>> {
        if depth > 16 {
            return None;
        }
        match connection_of(input)? {
            Connection::Node(name, _) => {
                let node = match place.graph {
                    Some(graph) => child_named(graph, name),
                    None => self.top.get(name).copied(),
                }?;
                self.enter(node, place, place.instance.or(place.graph).into_iter().collect())
            }
            Connection::Graph(name, output) => {
                let graph = self.top.get(name).copied().filter(|g| is_graph(*g))?;
                let node = graph_output(graph, output)?;
                self.enter(node, Place { graph: Some(graph), instance: None }, vec![graph])
            }
            Connection::Interface(name) => {
                let source = match place.instance {
                    Some(instance) => inputs(instance).find(|i| i.attribute("name") == Some(name)),
                    None => inputs(place.graph?).find(|i| i.attribute("name") == Some(name)),
                }?;
                self.shader_of(source, Place::TOP, depth + 1)
            }
        }
    }

    /// `node` at `place` inside `holders` as a shader: itself, or for a node the document
    /// defines, the shader its graph outputs.
    fn enter(
        &self,
        node: Node<'a, 'i>,
        place: Place<'a, 'i>,
        mut holders: Vec<Node<'a, 'i>>,
    ) -> Option<Located<'a, 'i>> {
        match self.implementation(node) {
            Some((_, graph)) => {
                holders.push(node);
                Some((graph_output(graph, None)?, Place { graph: Some(graph), instance: Some(node) }, holders))
            }
            None => Some((node, place, holders)),
        }
    }

    /// Records, for every `nodename` connection, the output it reads on its producer.
    fn collect_outputs(&mut self, root: Node<'a, 'i>) {
        for input in root.descendants().filter(|n| n.is_element() && matches!(n.tag_name().name(), "input" | "output"))
        {
            let Some(node_name) = input.attribute("nodename") else { continue };
            let Some(owner) = input.parent_element() else { continue };
            // An `<output>` of a graph and an `<input>` of a node both read a sibling node
            // of the element that holds them (the graph, or the node's parent).
            let scope = if input.tag_name().name() == "output" { Some(owner) } else { owner.parent_element() };
            let Some(producer) = scope.and_then(|s| child_named(s, node_name)) else { continue };
            let output = input.attribute("output").unwrap_or("out").to_string();
            let ty = input.attribute("type").unwrap_or("float").to_string();
            let list = self.outputs.entry(producer.id()).or_default();
            if !list.iter().any(|(n, _)| *n == output) {
                list.push((output, ty));
            }
        }
    }

    /// `/MaterialX/Materials/<name>` and the network it uses, for material node `material`
    /// living at `place` (or the document-defined material node `material` stands for).
    fn material(&mut self, out: &mut String, name: &str, material: Node<'a, 'i>, place: Place<'a, 'i>) {
        let (material, place) = match (place.graph, self.implementation(material)) {
            (None, Some((_, graph))) => {
                let output = graph.children().find(|o| {
                    o.is_element() && o.tag_name().name() == "output" && o.attribute("type") == Some("material")
                });
                match output.and_then(|o| o.attribute("nodename")).and_then(|n| child_named(graph, n)) {
                    Some(node) => (node, Place { graph: Some(graph), instance: Some(material) }),
                    None => (material, place),
                }
            }
            _ => (material, place),
        };
        let name = identifier(name);
        let path = format!("/MaterialX/Materials/{name}");
        let _ = writeln!(out, "        def Material \"{name}\"\n        {{");
        // The nodes and graphs the material's shaders reach, each copied once under it.
        let mut needed: Vec<Node> = Vec::new();
        let mut terminals = Vec::new();
        for input in inputs(material) {
            if connection_of(input).is_none() {
                // `value=""` is MaterialX's way of saying "no shader".
                if input.attribute("value") != Some("") {
                    let input_name = input.attribute("name").unwrap_or("");
                    self.warn(input, format!("material input `{input_name}` connects to no shader node"));
                }
                continue;
            }
            let Some((shader, _, holders)) = self.shader_of(input, place, 0) else {
                let message = match connection_of(input) {
                    Some(Connection::Interface(name)) => {
                        format!("material input reads the graph's input `{name}`, which connects to no shader")
                    }
                    _ => {
                        let target = input.attribute("nodename").or(input.attribute("nodegraph")).unwrap_or("");
                        format!("material input names node `{target}`, which the document does not define")
                    }
                };
                self.warn(input, message);
                continue;
            };
            let terminal = match input.attribute("type").or(shader.attribute("type")) {
                Some("displacementshader") => "displacement",
                Some("volumeshader") => "volume",
                _ => "surface",
            };
            // A shader inside a graph is written with its graph (a document-defined node as
            // the graph of its definition, under the node's name).
            let mut shader_path = path.clone();
            for prim in holders.iter().chain([&shader]) {
                let _ = write!(shader_path, "/{}", identifier(prim.attribute("name").unwrap_or("")));
            }
            terminals.push((terminal, shader, shader_path, holders.is_empty()));
            self.reach(holders.first().copied().unwrap_or(shader), &mut needed);
        }
        // A top-level surface shader's values become the Material's interface, as usdMtlx does.
        let surface = terminals.iter().find(|(t, _, _, top)| *t == "surface" && *top).map(|(_, s, _, _)| *s);
        let mut promoted = HashSet::new();
        if let Some(shader) = surface {
            for input in inputs(shader) {
                let Some(input_name) = input.attribute("name") else { continue };
                if input.attribute("value").is_some() && connection_of(input).is_none() {
                    let decl = self.value_decl(input, &format!("inputs:{}", identifier(input_name)));
                    if let Some(decl) = decl {
                        let _ = writeln!(out, "            {decl}");
                        promoted.insert(input.id());
                    }
                }
            }
        }
        for (terminal, shader, shader_path, _) in &terminals {
            let output = shader_output(*shader);
            let _ =
                writeln!(out, "            token outputs:mtlx:{terminal}.connect = <{shader_path}.outputs:{output}>");
        }
        if !terminals.iter().any(|(t, ..)| *t == "surface") {
            // A material without a surface shader still is one: it shades with the default
            // substance, after a warning, when bound.
            let _ = writeln!(out, "            token outputs:mtlx:surface");
        }
        for node in needed {
            if is_graph(node) {
                let graph_name = identifier(node.attribute("name").unwrap_or(""));
                self.node_graph(out, node, &format!("{path}/{graph_name}"), 3, Some(&path), None);
            } else {
                self.node(out, node, &path, 3, &promoted);
            }
        }
        out.push_str("        }\n\n");
    }

    /// Adds `node` and the top-level nodes and graphs it reads, dependencies first, each once.
    fn reach(&mut self, node: Node<'a, 'i>, needed: &mut Vec<Node<'a, 'i>>) {
        let mut stack = vec![(node, false)];
        while let Some((n, expanded)) = stack.pop() {
            if needed.iter().any(|x| x.id() == n.id()) {
                continue;
            }
            if expanded {
                needed.push(n);
                continue;
            }
            stack.push((n, true));
            // A node's inputs, or a graph's interface inputs, read top-level elements.
            for input in inputs(n) {
                let target = input.attribute("nodename").or(input.attribute("nodegraph"));
                let Some(target) = target else { continue };
                match self.top.get(target).copied() {
                    Some(dep) if dep.id() != n.id() => stack.push((dep, false)),
                    _ => self.warn(input, format!("input connects to `{target}`, which the document does not define")),
                }
            }
        }
    }

    /// A `NodeGraph` prim at `path` for `<nodegraph>` `graph`. Its interface inputs connect
    /// to prims under `scope` (the prim holding the graph; `None`, a library graph: to the
    /// top-level elements it reads, copied inside it); for the graph
    /// of a document-defined node, the interface is the definition's inputs, set by `instance`.
    fn node_graph(
        &mut self,
        out: &mut String,
        graph: Node<'a, 'i>,
        path: &str,
        depth: usize,
        scope: Option<&str>,
        instance: Option<Node<'a, 'i>>,
    ) {
        let pad = "    ".repeat(depth);
        let name = path.rsplit('/').next().unwrap_or("graph");
        let _ = writeln!(out, "{pad}def NodeGraph \"{name}\"\n{pad}{{");
        // A library graph (`/MaterialX/NodeGraphs/<name>`, which USD may reference straight)
        // carries the top-level nodes and graphs its interface reads inside it, so that its
        // interface connections travel with a reference to it (usdMtlx drops them).
        let mut carried = Vec::new();
        let scope = match (scope, instance) {
            (None, None) => {
                self.reach(graph, &mut carried);
                carried.retain(|n| n.id() != graph.id());
                let (clashes, kept): (Vec<Node>, Vec<Node>) = carried
                    .into_iter()
                    .partition(|n| n.attribute("name").and_then(|m| child_named(graph, m)).is_some());
                carried = kept;
                for clash in clashes {
                    let clash_name = clash.attribute("name").unwrap_or("");
                    let message = format!(
                        "graph `{name}` reads top-level `{clash_name}` and has a node of that name; \
                         /MaterialX/NodeGraphs/{name} reads its own node"
                    );
                    self.warn(clash, message);
                }
                Some(path)
            }
            _ => scope,
        };
        let interface: Vec<Node> = match instance.and_then(|i| self.implementation(i)) {
            Some((def, _)) => inputs(def).collect(),
            None => inputs(graph).collect(),
        };
        let mut geometry = BTreeSet::new();
        for declared in interface {
            let Some(input_name) = declared.attribute("name") else { continue };
            let attr = format!("inputs:{}", identifier(input_name));
            let input =
                instance.and_then(|i| inputs(i).find(|x| x.attribute("name") == Some(input_name))).unwrap_or(declared);
            let usd_ty = usd_type(input.attribute("type").unwrap_or("float")).unwrap_or("token");
            if let Some(line) = scope.and_then(|scope| self.connection_line(input, &attr, usd_ty, scope)) {
                let _ = writeln!(out, "{pad}    {line}");
                continue;
            }
            let property = input.attribute("defaultgeomprop").or(input.attribute("geomprop"));
            if let (None, Some(property)) = (input.attribute("value"), property) {
                // The geometric property is read by a node in the graph (usdMtlx leaves the
                // input unset and lets the renderer's default apply).
                match geomprop_node(property) {
                    Some(node) => {
                        let _ = writeln!(
                            out,
                            "{pad}    {usd_ty} {attr}.connect = <{path}/strata_geomprop_{property}.outputs:out>"
                        );
                        geometry.insert((property, node));
                    }
                    None => self.warn(
                        input,
                        format!("geometric property `{property}` is not read; `{input_name}` keeps its default"),
                    ),
                }
                continue;
            }
            if let Some(decl) = self.value_decl(input, &attr) {
                let _ = writeln!(out, "{pad}    {decl}");
            }
        }
        for output in graph.children().filter(|c| c.is_element() && c.tag_name().name() == "output") {
            let Some(output_name) = output.attribute("name") else { continue };
            let ty = usd_type(output.attribute("type").unwrap_or("float")).unwrap_or("token");
            match output.attribute("nodename").map(|node| self.films.reads(graph, node)) {
                Some(node) if child_named(graph, node).is_some() => {
                    let from = identifier(output.attribute("output").unwrap_or("out"));
                    let _ = writeln!(
                        out,
                        "{pad}    {ty} outputs:{}.connect = <{path}/{}.outputs:{from}>",
                        identifier(output_name),
                        identifier(node)
                    );
                }
                Some(node) => {
                    self.warn(output, format!("graph output reads node `{node}`, which the graph does not define"))
                }
                None => {
                    let _ = writeln!(out, "{pad}    {ty} outputs:{}", identifier(output_name));
                }
            }
        }
        for (property, (id, space)) in geometry {
            let _ = writeln!(out, "{pad}    def Shader \"strata_geomprop_{property}\"\n{pad}    {{");
            let _ = writeln!(out, "{pad}        uniform token info:id = \"{id}\"");
            if let Some(space) = space {
                let _ = writeln!(out, "{pad}        string inputs:space = \"{space}\"");
            }
            let ty = if id == "ND_texcoord_vector2" { "float2" } else { "float3" };
            let _ = writeln!(out, "{pad}        {ty} outputs:out\n{pad}    }}\n");
        }
        for node in graph.children().filter(|c| c.is_element()) {
            let tag = node.tag_name().name();
            // Material nodes in a graph become Materials of their own (`translate`).
            if NON_NODES.contains(&tag) || node.attribute("type") == Some("material") {
                continue;
            }
            if tag == "nodegraph" {
                self.warn(node, "a node graph nested in a node graph is not supported; it is ignored".into());
                continue;
            }
            if node.attribute("name").is_none() {
                self.warn(node, format!("`<{tag}>` has no `name`; it is ignored"));
                continue;
            }
            self.node(out, node, path, depth + 1, &HashSet::new());
        }
        for node in carried {
            if is_graph(node) {
                let graph_name = identifier(node.attribute("name").unwrap_or(""));
                self.node_graph(out, node, &format!("{path}/{graph_name}"), depth + 1, Some(path), None);
            } else {
                self.node(out, node, path, depth + 1, &HashSet::new());
            }
        }
        let _ = writeln!(out, "{pad}}}\n");
    }

    /// `type attr.connect = <...>` for a connected input of a node or graph under `scope`; a
    /// top-level node's `interfacename` reads the document's top-level `<input>` (its value).
    fn connection_line(&mut self, input: Node<'a, 'i>, attr: &str, usd_ty: &str, scope: &str) -> Option<String> {
        Some(match connection_of(input)? {
            Connection::Node(target, output) => {
                // A node's input reads a sibling of the node (a graph's interface input, a
                // sibling of the graph).
                let target = match input.parent_element().and_then(|owner| owner.parent_element()) {
                    Some(scope) => self.films.reads(scope, target),
                    None => target,
                };
                format!("{usd_ty} {attr}.connect = <{scope}/{}.outputs:{}>", identifier(target), identifier(output))
            }
            Connection::Graph(graph, output) => {
                let output = output.map(str::to_string).or_else(|| self.first_output(graph));
                let output = output.unwrap_or_else(|| "out".into());
                format!("{usd_ty} {attr}.connect = <{scope}/{}.outputs:{}>", identifier(graph), identifier(&output))
            }
            Connection::Interface(interface) => {
                let owner = input.parent_element();
                let at_top = owner.and_then(|o| o.parent_element()).is_some_and(|p| p.tag_name().name() == "materialx");
                let document_input = self.top.get(interface).copied().filter(|n| n.tag_name().name() == "input");
                match document_input {
                    Some(source) if at_top && !owner.is_some_and(is_graph) => return self.value_decl(source, attr),
                    _ => format!("{usd_ty} {attr}.connect = <{scope}.inputs:{}>", identifier(interface)),
                }
            }
        })
    }

    /// A `Shader` prim for node `node`; connections resolve against `scope`, the prim it is
    /// written under (its graph, or the material its top-level network was copied into). Inputs in
    /// `promoted` connect to the Material's interface input of the same name.
    fn node(
        &mut self,
        out: &mut String,
        node: Node<'a, 'i>,
        scope: &str,
        depth: usize,
        promoted: &HashSet<roxmltree::NodeId>,
    ) {
        let name = identifier(node.attribute("name").unwrap_or("node"));
        if let Some((_, graph)) = self.implementation(node) {
            // A node the document defines by a graph: the graph, under the node's name.
            self.node_graph(out, graph, &format!("{scope}/{name}"), depth, Some(scope), Some(node));
            return;
        }
        let pad = "    ".repeat(depth);
        let id = nodedef_id(node);
        let _ = writeln!(out, "{pad}def Shader \"{name}\"\n{pad}{{\n{pad}    uniform token info:id = \"{id}\"");
        let film = self.films.film_of(node);
        let film_input = |name: &str| film.and_then(|f| inputs(f).find(|i| i.attribute("name") == Some(name)));
        // A film's input replaces the BSDF's own (MaterialX copies it over).
        let own = inputs(node).filter(|i| {
            !FILM_INPUTS.iter().any(|(from, to)| i.attribute("name") == Some(to) && film_input(from).is_some())
        });
        let taken = FILM_INPUTS.iter().filter_map(|(from, to)| Some((film_input(from)?, Some(*to))));
        let all: Vec<(Node, Option<&str>)> = own.map(|i| (i, None)).chain(taken).collect();
        for (input, renamed) in all {
            let Some(input_name) = renamed.or(input.attribute("name")) else { continue };
            let attr = format!("inputs:{}", identifier(input_name));
            let ty = input.attribute("type").unwrap_or("float");
            let Some(usd_ty) = usd_type(ty) else {
                self.warn(
                    input,
                    format!("input `{input_name}` has type `{ty}`, which strata does not read; it is ignored"),
                );
                continue;
            };
            if promoted.contains(&input.id()) {
                let _ = writeln!(out, "{pad}    {usd_ty} {attr}.connect = <{scope}.{attr}>");
                continue;
            }
            match self.connection_line(input, &attr, usd_ty, scope) {
                Some(line) => {
                    let _ = writeln!(out, "{pad}    {line}");
                }
                None if connection_of(input).is_some() => {}
                None => {
                    if let Some(decl) = self.value_decl(input, &attr) {
                        let _ = writeln!(out, "{pad}    {decl}");
                    }
                }
            }
        }
        let own = (shader_output(node).to_string(), node.attribute("type").unwrap_or("float").to_string());
        let mut outputs: BTreeSet<(String, String)> = BTreeSet::new();
        if own.1 != "multioutput" {
            outputs.insert(own);
        }
        for o in node.children().filter(|c| c.is_element() && c.tag_name().name() == "output") {
            if let Some(n) = o.attribute("name") {
                outputs.insert((n.to_string(), o.attribute("type").unwrap_or("float").to_string()));
            }
        }
        for (o, ty) in self.outputs.get(&node.id()).into_iter().flatten() {
            if !outputs.iter().any(|(n, _)| n == o) {
                outputs.insert((o.clone(), ty.clone()));
            }
        }
        for (o, ty) in outputs {
            let _ = writeln!(out, "{pad}    {} outputs:{}", usd_type(&ty).unwrap_or("token"), identifier(&o));
        }
        let _ = writeln!(out, "{pad}}}\n");
    }

    /// The first output of top-level graph `graph`.
    fn first_output(&self, graph: &str) -> Option<String> {
        let g = self.top.get(graph)?;
        g.children()
            .find(|c| c.is_element() && c.tag_name().name() == "output")
            .and_then(|o| o.attribute("name"))
            .map(str::to_string)
    }

    /// `type name = value (metadata)` for an input's authored value; `None` (after a warning
    /// when a value was there) when it has none strata can read.
    fn value_decl(&mut self, input: Node, attr: &str) -> Option<String> {
        let ty = input.attribute("type").unwrap_or("float");
        let usd_ty = usd_type(ty)?;
        let mut meta = String::new();
        if matches!(ty, "color3" | "color4" | "filename")
            && let Some(space) = inherited(input, "colorspace")
        {
            meta = format!(" (\n    colorSpace = \"{}\"\n)", escape(space));
        }
        let Some(text) = input.attribute("value") else {
            if input.attribute("geomprop").is_none() && input.attribute("defaultgeomprop").is_none() {
                return Some(format!("{usd_ty} {attr}{meta}"));
            }
            return None;
        };
        match usd_value(ty, text, input) {
            Ok(value) => Some(format!("{usd_ty} {attr} = {value}{meta}")),
            Err(why) => {
                let name = input.attribute("name").unwrap_or("");
                self.warn(input, format!("input `{name}`: {why}; the node's default is used"));
                None
            }
        }
    }
}

/// How an input is connected.
enum Connection<'x> {
    /// `nodename` (+ `output`).
    Node(&'x str, &'x str),
    /// `nodegraph` (+ `output`).
    Graph(&'x str, Option<&'x str>),
    /// `interfacename`.
    Interface(&'x str),
}

fn connection_of<'x>(input: Node<'x, '_>) -> Option<Connection<'x>> {
    if let Some(n) = input.attribute("nodename") {
        return Some(Connection::Node(n, input.attribute("output").unwrap_or("out")));
    }
    if let Some(g) = input.attribute("nodegraph") {
        return Some(Connection::Graph(g, input.attribute("output")));
    }
    input.attribute("interfacename").map(Connection::Interface)
}

fn inputs<'a, 'i>(node: Node<'a, 'i>) -> impl Iterator<Item = Node<'a, 'i>> {
    node.children().filter(|c| c.is_element() && c.tag_name().name() == "input")
}

fn child_named<'a, 'i>(parent: Node<'a, 'i>, name: &str) -> Option<Node<'a, 'i>> {
    parent.children().find(|c| c.is_element() && c.attribute("name") == Some(name))
}

/// An attribute's value on the element or its nearest ancestor that has it (MaterialX's
/// scoping of `colorspace` and `fileprefix`).
fn inherited<'a>(node: Node<'a, '_>, key: &str) -> Option<&'a str> {
    node.ancestors().find_map(|n| n.attribute(key)).filter(|v| !v.is_empty())
}

/// The output a shader node's connection reads: usdMtlx names a shader's output after its
/// terminal (`surface`, `displacement`, `volume`), any other node's `out`.
fn shader_output(node: Node) -> &'static str {
    match node.attribute("type") {
        Some("surfaceshader") => "surface",
        Some("displacementshader") => "displacement",
        Some("volumeshader") => "volume",
        _ => "out",
    }
}

/// The node definition a node uses: `nodedef` when authored, else the standard library's
/// naming (`ND_<category>_<type>`; `FA` when a float drives a vector operation; the input's
/// type for conversions and channel extraction).
pub fn nodedef_id(node: Node) -> String {
    if let Some(def) = node.attribute("nodedef") {
        return def.to_string();
    }
    let category = node.tag_name().name();
    let ty = node.attribute("type").unwrap_or("float");
    let input_type =
        |name: &str| inputs(node).find(|i| i.attribute("name") == Some(name)).and_then(|i| i.attribute("type"));
    let in_ty = input_type("in").unwrap_or("float");
    match category {
        // pbrlib: closure operators are named by their closure type (`ND_layer_bsdf`,
        // `ND_multiply_bsdfF`), lobes and EDFs by their category alone, as is `surface`.
        "multiply" if matches!(ty, "BSDF" | "EDF" | "VDF") => {
            let by = if input_type("in2") == Some("float") { "F" } else { "C" };
            format!("ND_multiply_{}{by}", ty.to_ascii_lowercase())
        }
        "layer" | "mix" | "add" if matches!(ty, "BSDF" | "EDF" | "VDF") => {
            format!("ND_{category}_{}", ty.to_ascii_lowercase())
        }
        _ if matches!(ty, "BSDF" | "EDF" | "VDF") => format!("ND_{category}"),
        "surface" | "surface_unlit" if ty == "surfaceshader" => format!("ND_{category}"),
        // pbrlib's utility nodes have one definition each, named by category alone.
        "artistic_ior" | "roughness_anisotropy" | "roughness_dual" | "glossiness_anisotropy" | "blackbody" => {
            format!("ND_{category}")
        }
        "convert" => format!("ND_convert_{in_ty}_{ty}"),
        // Conditionals selected by an integer or a boolean name it after the output type.
        "ifgreater" | "ifgreatereq" | "ifequal" | "switch" => {
            let selector = input_type(if category == "switch" { "which" } else { "value1" });
            let by = match selector {
                Some("integer") => "I",
                Some("boolean") if category == "ifequal" => "B",
                _ => "",
            };
            format!("ND_{category}_{ty}{by}")
        }
        // 1.39 names normal maps by the type of `scale`.
        "normalmap" => format!("ND_normalmap_{}", input_type("scale").unwrap_or("float")),
        "extract" => format!("ND_extract_{in_ty}"),
        // A 4-channel combine2 is named by what it combines: a triple and a float (CF, VF) or
        // two vector2s (VV).
        "combine2" if matches!(ty, "color4" | "vector4") => {
            let by = match (ty, input_type("in1")) {
                (_, Some("vector2")) => "VV",
                ("color4", _) => "CF",
                _ => "VF",
            };
            format!("ND_combine2_{ty}{by}")
        }
        // Nodes that reduce a vector are named by the vector's type.
        "magnitude" | "mincomponent" | "maxcomponent" => format!("ND_{category}_{in_ty}"),
        "dotproduct" | "distance" => format!("ND_{category}_{}", input_type("in1").unwrap_or("vector3")),
        // MaterialX's `usd` library names its texture node without a type.
        "UsdUVTexture" => "ND_UsdUVTexture".to_string(),
        "separate2" | "separate3" | "separate4" => format!("ND_{category}_{in_ty}"),
        _ if ty == "multioutput" => format!("ND_{category}_{in_ty}"),
        "add" | "subtract" | "multiply" | "divide" | "modulo" | "power" | "min" | "max" | "clamp" | "smoothstep"
        | "remap"
            if ty != "float"
                && ["in2", "low", "high", "inlow", "inhigh", "outlow", "outhigh"]
                    .iter()
                    .any(|n| input_type(n) == Some("float")) =>
        {
            format!("ND_{category}_{ty}FA")
        }
        _ => format!("ND_{category}_{ty}"),
    }
}

/// The USD value type of a MaterialX type, as usdMtlx writes it.
pub fn usd_type(ty: &str) -> Option<&'static str> {
    Some(match ty {
        "float" => "float",
        "integer" => "int",
        "boolean" => "bool",
        "color3" => "color3f",
        "color4" => "color4f",
        "vector2" => "float2",
        "vector3" => "float3",
        "vector4" => "float4",
        "matrix33" => "matrix3d",
        "matrix44" => "matrix4d",
        "string" => "string",
        "filename" => "asset",
        "surfaceshader" | "displacementshader" | "volumeshader" | "lightshader" | "material" | "BSDF" | "EDF"
        | "VDF" => "token",
        _ => return None,
    })
}

/// A MaterialX value string as USDA.
fn usd_value(ty: &str, text: &str, input: Node) -> Result<String, String> {
    let numbers = |n: usize| -> Result<String, String> {
        let parts: Vec<&str> = text.split(',').map(str::trim).collect();
        if parts.len() != n {
            return Err(format!("`{text}` is not a {ty} ({n} numbers separated by commas)"));
        }
        let mut values = Vec::with_capacity(n);
        for p in parts {
            match p.parse::<f64>() {
                Ok(v) if v.is_finite() => values.push(format!("{v:?}")),
                _ => return Err(format!("`{p}` is not a finite number")),
            }
        }
        Ok(if n == 1 { values.remove(0) } else { format!("({})", values.join(", ")) })
    };
    match ty {
        "float" => numbers(1),
        "color3" | "vector3" => numbers(3),
        "vector2" => numbers(2),
        "color4" | "vector4" => numbers(4),
        "integer" => {
            text.trim().parse::<i32>().map(|v| v.to_string()).map_err(|_| format!("`{text}` is not an integer"))
        }
        "boolean" => match text.trim() {
            "true" => Ok("1".into()),
            "false" => Ok("0".into()),
            _ => Err(format!("`{text}` is not a boolean (`true` or `false`)")),
        },
        "matrix33" | "matrix44" => {
            let n = if ty == "matrix33" { 3 } else { 4 };
            let rows = numbers(n * n)?;
            let inner = rows.trim_start_matches('(').trim_end_matches(')');
            let v: Vec<&str> = inner.split(", ").collect();
            let rows: Vec<String> = v.chunks(n).map(|r| format!("({})", r.join(", "))).collect();
            Ok(format!("({})", rows.join(", ")))
        }
        "filename" => {
            let prefix = inherited(input, "fileprefix").unwrap_or("");
            let absolute = text.starts_with('/') || text.contains("://");
            let path = if absolute || text.is_empty() { text.to_string() } else { format!("{prefix}{text}") };
            if path.contains('@') {
                return Err(format!("file name `{path}` contains `@`"));
            }
            Ok(format!("@{path}@"))
        }
        "string" => Ok(format!("\"{}\"", escape(text))),
        _ => Err(format!("values of type `{ty}` are not read")),
    }
}

fn escape(text: &str) -> String {
    text.replace('\\', "\\\\").replace('"', "\\\"").replace('\n', "\\n")
}

/// A MaterialX name as a USD identifier (characters outside `[A-Za-z0-9_]` become `_`).
pub fn identifier(name: &str) -> String {
    let mut s: String = name.chars().map(|c| if c.is_ascii_alphanumeric() || c == '_' { c } else { '_' }).collect();
    if s.is_empty() || s.starts_with(|c: char| c.is_ascii_digit()) {
        s.insert(0, '_');
    }
    s
}

/// The start tag of an element (what a diagnostic underlines).
fn tag_range(node: Node) -> Range<usize> {
    let r = node.range();
    let text = node.document().input_text();
    let end = text[r.clone()].find('>').map_or(r.end, |i| r.start + i + 1);
    r.start..end
}

/// The byte offset of 1-based `row`, `col` (in characters) in `text`.
fn offset_of(text: &str, row: usize, col: usize) -> usize {
    let line_start: usize = text.split_inclusive('\n').take(row.saturating_sub(1)).map(str::len).sum();
    let line = text[line_start.min(text.len())..].split('\n').next().unwrap_or("");
    line_start + line.char_indices().nth(col.saturating_sub(1)).map_or(line.len(), |(i, _)| i)
}

#[cfg(test)]
mod tests {
    use super::*;

    const DOC: &str = r#"<?xml version="1.0"?>
<materialx version="1.39" colorspace="lin_rec709" fileprefix="tex/">
  <nodegraph name="NG_base">
    <input name="scale" type="float" value="2" />
    <image name="img" type="color3">
      <input name="file" type="filename" value="base.png" colorspace="srgb_texture" />
    </image>
    <multiply name="mul" type="color3">
      <input name="in1" type="color3" nodename="img" />
      <input name="in2" type="float" interfacename="scale" />
    </multiply>
    <output name="out_color" type="color3" nodename="mul" />
  </nodegraph>
  <open_pbr_surface name="SR_piece" type="surfaceshader">
    <input name="base_color" type="color3" nodegraph="NG_base" output="out_color" />
    <input name="specular_roughness" type="float" value="0.25" />
  </open_pbr_surface>
  <surfacematerial name="M_piece" type="material">
    <input name="surfaceshader" type="surfaceshader" nodename="SR_piece" />
  </surfacematerial>
</materialx>
"#;

    #[test]
    fn materials_graphs_and_connections_translate_as_usdmtlx_does() {
        let t = translate(DOC).expect("translates");
        assert!(t.warnings.is_empty(), "{:?}", t.warnings);
        let u = &t.usda;
        for line in [
            "def Material \"M_piece\"",
            "float inputs:specular_roughness = 0.25",
            "token outputs:mtlx:surface.connect = </MaterialX/Materials/M_piece/SR_piece.outputs:surface>",
            "uniform token info:id = \"ND_open_pbr_surface_surfaceshader\"",
            "float inputs:specular_roughness.connect = </MaterialX/Materials/M_piece.inputs:specular_roughness>",
            "color3f inputs:base_color.connect = </MaterialX/Materials/M_piece/NG_base.outputs:out_color>",
            "color3f outputs:out_color.connect = </MaterialX/Materials/M_piece/NG_base/mul.outputs:out>",
            "uniform token info:id = \"ND_multiply_color3FA\"",
            "float inputs:in2.connect = </MaterialX/Materials/M_piece/NG_base.inputs:scale>",
            "asset inputs:file = @tex/base.png@ (",
            "colorSpace = \"srgb_texture\"",
            "def NodeGraph \"NG_base\"",
            "color3f inputs:in1.connect = </MaterialX/NodeGraphs/NG_base/img.outputs:out>",
        ] {
            assert!(u.contains(line), "missing `{line}` in\n{u}");
        }
    }

    #[test]
    fn malformed_documents_are_located() {
        let e = translate("<materialx>\n  <image name=\"a\" type=\"color3\">\n</materialx>").unwrap_err();
        assert!(e.message.starts_with("malformed MaterialX document"), "{e:?}");
        let text = "<materialx>\n  <image name=\"a\" type=\"color3\">\n</materialx>";
        assert_eq!(text[..e.range.start].matches('\n').count() + 1, 3, "line 3: {e:?}");
        let e = translate("<usd/>").unwrap_err();
        assert!(e.message.contains("root element is `<usd>`"), "{e:?}");
    }

    #[test]
    fn bad_values_and_missing_nodes_are_warnings_at_their_element() {
        let doc = r#"<materialx>
  <standard_surface name="S" type="surfaceshader">
    <input name="base" type="float" value="lots" />
    <input name="base_color" type="color3" nodename="nowhere" />
  </standard_surface>
  <surfacematerial name="M" type="material">
    <input name="surfaceshader" type="surfaceshader" nodename="S" />
  </surfacematerial>
</materialx>"#;
        let t = translate(doc).unwrap();
        let messages: Vec<&str> = t.warnings.iter().map(|w| w.message.as_str()).collect();
        assert!(messages.iter().any(|m| m.contains("`lots` is not a finite number")), "{messages:?}");
        assert!(messages.iter().any(|m| m.contains("`nowhere`")), "{messages:?}");
        assert!(doc[t.warnings[0].range.clone()].starts_with("<input"), "{:?}", t.warnings);
    }

    #[test]
    fn document_defined_nodes_are_their_definition_s_graph_per_version() {
        // MaterialX's own test document: two versions of `myimage`, each a graph reading a
        // different default file; an instance takes the version it names, else the default.
        let doc = include_str!("../../tests/fixtures/mtlx/suite/TestSuite/stdlib/version/multiple_version_test.mtlx");
        let t = translate(doc).expect("translates");
        assert!(t.warnings.is_empty(), "{:?}", t.warnings);
        let wrap = |instance: &str| {
            let extra = format!(
                "<uniform_edf name=\"e\" type=\"EDF\"><input name=\"color\" type=\"color3\" nodename=\"{instance}\" /></uniform_edf>\
                 <surface name=\"s\" type=\"surfaceshader\"><input name=\"edf\" type=\"EDF\" nodename=\"e\" /></surface>\
                 <surfacematerial name=\"m\" type=\"material\"><input name=\"surfaceshader\" type=\"surfaceshader\" nodename=\"s\" /></surfacematerial></materialx>"
            );
            translate(&doc.replace("</materialx>", &extra)).expect("translates").usda
        };
        for (instance, file) in [
            ("image_version1_instance", "grid.png"),
            ("image_version2_instance", "cloth.png"),
            ("image_version2_implicit_instance", "cloth.png"),
        ] {
            let usda = wrap(instance);
            let graph = usda.find(&format!("def NodeGraph \"{instance}\"")).unwrap_or_else(|| panic!("{usda}"));
            let graph = &usda[graph..];
            let inputs = &graph[..graph.find("def Shader").unwrap()];
            assert!(inputs.contains(&format!("asset inputs:file = @resources/Images/{file}@")), "{instance}: {inputs}");
            assert!(graph.contains(".inputs:file>"), "the image reads the graph's input: {graph}");
        }
        // No NodeGraph is written for the definitions themselves.
        assert!(!t.usda.contains("NG_myimage"), "{}", t.usda);
    }

    #[test]
    fn graph_inputs_default_to_their_geometric_property() {
        let doc = include_str!("../../tests/fixtures/mtlx/suite/TestSuite/stdlib/defaultgeomprop/defaultgeomprop.mtlx");
        let t = translate(doc).expect("translates");
        assert!(t.warnings.is_empty(), "{:?}", t.warnings);
        let graph = "/MaterialX/Materials/defaultgeomprop/checkerboard1";
        assert!(
            t.usda.contains(&format!("float2 inputs:texcoord.connect = <{graph}/strata_geomprop_UV0.outputs:out>")),
            "{}",
            t.usda
        );
        assert!(t.usda.contains("uniform token info:id = \"ND_texcoord_vector2\""), "{}", t.usda);
    }

    #[test]
    fn a_library_graph_carries_the_top_level_nodes_its_interface_reads() {
        let doc = r#"<materialx>
  <constant name="c" type="color3"><input name="value" type="color3" value="0.2, 0.4, 0.6" /></constant>
  <nodegraph name="NG_inner"><input name="x" type="color3" nodename="c" />
    <output name="out" type="color3" interfacename="x" /></nodegraph>
  <nodegraph name="NG">
    <input name="base" type="color3" nodename="c" />
    <input name="other" type="color3" nodegraph="NG_inner" output="out" />
    <multiply name="m" type="color3"><input name="in1" type="color3" interfacename="base" /></multiply>
    <output name="out" type="color3" nodename="m" />
  </nodegraph>
</materialx>"#;
        let t = translate(doc).unwrap();
        assert!(t.warnings.is_empty(), "{:?}", t.warnings);
        for line in [
            "color3f inputs:base.connect = </MaterialX/NodeGraphs/NG/c.outputs:out>",
            "color3f inputs:other.connect = </MaterialX/NodeGraphs/NG/NG_inner.outputs:out>",
            "color3f inputs:x.connect = </MaterialX/NodeGraphs/NG/c.outputs:out>",
            "color3f inputs:x.connect = </MaterialX/NodeGraphs/NG_inner/c.outputs:out>",
        ] {
            assert!(t.usda.contains(line), "missing `{line}` in\n{}", t.usda);
        }
        // The constant is written once inside each library graph that reads it (NG's copy of
        // NG_inner reads NG's).
        assert_eq!(t.usda.matches("def Shader \"c\"").count(), 2, "{}", t.usda);
    }
}
