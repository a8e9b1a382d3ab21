//! USD path expressions (`SdfPathExpression`), as collections' `membershipExpression` uses
//! them: path patterns with globs (`*`, `?`, `[...]`) in name elements, `//` for any number
//! of levels, brace-enclosed predicates (`{isa:Mesh}`), references to the weaker expression
//! (`%_`) and to other collections (`%/World:set`), joined by `~` (complement), implied union
//! (whitespace), `+`, `&` and `-`, tightest first, each left-associative, as usd-core 0.26
//! parses them. [`PathExpression::parse`] reports the first malformed spot by its byte offset;
//! [`Matcher`] tests one prim at a time against the stage's prim hierarchy.

use crate::scene::{PrimId, Stage};

/// A parsed path expression.
#[derive(Clone, Debug, PartialEq)]
pub struct PathExpression {
    root: Node,
}

/// Why an expression is malformed: the byte offset into its text and what was expected.
#[derive(Clone, Debug, PartialEq)]
pub struct ParseError {
    /// Byte offset of the offending character (the text's length at its end).
    pub offset: usize,
    /// What went wrong, for the diagnostic.
    pub message: String,
}

#[derive(Clone, Debug, PartialEq)]
enum Node {
    Pattern(Pattern),
    /// `%_`: the next weaker opinion's expression (nothing when there is none).
    Weaker,
    /// `%/path:name`: the members of collection `name` on prim `path` (relative to the anchor).
    Collection {
        prim: String,
        name: String,
        offset: usize,
    },
    Complement(Box<Node>),
    Union(Box<Node>, Box<Node>),
    Intersection(Box<Node>, Box<Node>),
    Difference(Box<Node>, Box<Node>),
}

/// A path pattern: steps from the anchor (absolute patterns from the root).
#[derive(Clone, Debug, PartialEq)]
struct Pattern {
    absolute: bool,
    steps: Vec<Step>,
    /// Ends in a property (`/a.size`): never a prim.
    property: bool,
}

#[derive(Clone, Debug, PartialEq)]
enum Step {
    /// `..`: the parent (only in a relative pattern's leading part).
    Parent,
    /// `//`: zero or more levels.
    AnyDepth,
    /// One level: a name glob (empty = any name) and an optional predicate.
    Element { glob: String, predicate: Option<Predicate> },
}

/// A predicate expression (`SdfPredicateExpression`): calls joined by `not`, implied and
/// (whitespace), `and`, `or`.
#[derive(Clone, Debug, PartialEq)]
enum Predicate {
    Call { name: String, args: Vec<Arg>, offset: usize },
    Not(Box<Predicate>),
    And(Box<Predicate>, Box<Predicate>),
    Or(Box<Predicate>, Box<Predicate>),
}

/// A predicate argument; `name` is empty for positional ones.
#[derive(Clone, Debug, PartialEq)]
struct Arg {
    name: String,
    value: String,
}

impl PathExpression {
    /// Parses `text`; an empty text is the empty expression (it matches nothing).
    pub fn parse(text: &str) -> Result<PathExpression, ParseError> {
        let mut p = Parser { text: text.as_bytes(), pos: 0 };
        p.skip_space();
        if p.at_end() {
            return Ok(PathExpression { root: Node::Complement(Box::new(Node::Pattern(everything()))) });
        }
        let root = p.difference()?;
        p.skip_space();
        if !p.at_end() {
            return Err(p.error("expected an operator (`+`, `&`, `-`) or the end of the expression"));
        }
        Ok(PathExpression { root })
    }

    /// The collections this expression references (`%/path:name`, path as written) with
    /// their offsets.
    pub fn collection_references(&self) -> Vec<(&str, &str, usize)> {
        fn walk<'e>(n: &'e Node, out: &mut Vec<(&'e str, &'e str, usize)>) {
            match n {
                Node::Collection { prim, name, offset } => out.push((prim, name, *offset)),
                Node::Complement(a) => walk(a, out),
                Node::Union(a, b) | Node::Intersection(a, b) | Node::Difference(a, b) => {
                    walk(a, out);
                    walk(b, out);
                }
                Node::Pattern(_) | Node::Weaker => {}
            }
        }
        let mut out = Vec::new();
        walk(&self.root, &mut out);
        out
    }
}

/// `//`, which every prim matches.
fn everything() -> Pattern {
    Pattern { absolute: true, steps: vec![Step::AnyDepth], property: false }
}

/// Answers what an expression needs from outside it: the weaker expression, referenced
/// collections' membership, and predicates strata cannot evaluate.
pub trait Context {
    /// Whether prim `id` matches the next weaker expression (`%_`); `false` when there is none.
    fn weaker_includes(&mut self, id: PrimId) -> bool;
    /// Whether collection `name` of prim `owner` (absolute) includes prim `id`; `offset` is
    /// where the reference is written, for a diagnostic.
    fn collection_includes(&mut self, owner: &str, name: &str, id: PrimId, offset: usize) -> bool;
    /// A predicate strata cannot evaluate, written at `offset`: it does not match.
    fn unevaluated(&mut self, predicate: &str, why: &str, offset: usize);
}

/// Tests prims of one stage against an expression anchored at a prim (a collection's owner).
pub struct Matcher<'s> {
    stage: &'s Stage,
    anchor: &'s str,
}

impl<'s> Matcher<'s> {
    /// Relative patterns and references resolve against `anchor` (an absolute prim path).
    pub fn new(stage: &'s Stage, anchor: &'s str) -> Matcher<'s> {
        Matcher { stage, anchor }
    }

    /// Whether prim `id` matches `expr`.
    pub fn matches(&self, expr: &PathExpression, id: PrimId, cx: &mut dyn Context) -> bool {
        let mut chain = vec![id];
        while let Some(parent) = self.stage.prim(*chain.last().expect("non-empty")).parent {
            chain.push(parent);
        }
        chain.reverse();
        self.node(&expr.root, &chain, cx)
    }

    fn node(&self, node: &Node, chain: &[PrimId], cx: &mut dyn Context) -> bool {
        let id = *chain.last().expect("a prim");
        match node {
            Node::Pattern(p) => self.pattern(p, chain, cx),
            Node::Weaker => cx.weaker_includes(id),
            Node::Collection { prim, name, offset } => match absolute(self.anchor, prim) {
                Some(owner) => cx.collection_includes(&owner, name, id, *offset),
                None => false,
            },
            Node::Complement(a) => !self.node(a, chain, cx),
            Node::Union(a, b) => self.node(a, chain, cx) | self.node(b, chain, cx),
            Node::Intersection(a, b) => self.node(a, chain, cx) & self.node(b, chain, cx),
            Node::Difference(a, b) => self.node(a, chain, cx) & !self.node(b, chain, cx),
        }
    }

    fn pattern(&self, p: &Pattern, chain: &[PrimId], cx: &mut dyn Context) -> bool {
        if p.property {
            return false;
        }
        // Anchor a relative pattern: the anchor's names, popped by leading `..`s.
        let mut prefix: Vec<Step> = Vec::new();
        let mut steps = p.steps.as_slice();
        if !p.absolute {
            let mut names: Vec<&str> = self.anchor.split('/').filter(|s| !s.is_empty()).collect();
            while let Some((Step::Parent, rest)) = steps.split_first() {
                if names.pop().is_none() {
                    return false;
                }
                steps = rest;
            }
            // Prim names hold no glob characters: each matches only itself.
            prefix = names.iter().map(|n| Step::Element { glob: n.to_string(), predicate: None }).collect();
        }
        let all: Vec<&Step> = prefix.iter().chain(steps).collect();
        self.steps(&all, chain, cx)
    }

    fn steps(&self, steps: &[&Step], chain: &[PrimId], cx: &mut dyn Context) -> bool {
        match steps.split_first() {
            None => chain.is_empty(),
            Some((Step::AnyDepth, rest)) => (0..=chain.len()).any(|k| self.steps(rest, &chain[k..], cx)),
            Some((Step::Parent, _)) => false,
            Some((Step::Element { glob, predicate }, rest)) => {
                let Some((&id, below)) = chain.split_first() else { return false };
                glob_matches(glob, &self.stage.prim(id).name)
                    && predicate.as_ref().is_none_or(|pred| self.predicate(pred, id, cx))
                    && self.steps(rest, below, cx)
            }
        }
    }

    fn predicate(&self, pred: &Predicate, id: PrimId, cx: &mut dyn Context) -> bool {
        match pred {
            Predicate::Not(a) => !self.predicate(a, id, cx),
            Predicate::And(a, b) => self.predicate(a, id, cx) && self.predicate(b, id, cx),
            Predicate::Or(a, b) => self.predicate(a, id, cx) || self.predicate(b, id, cx),
            Predicate::Call { name, args, offset } => match self.call(name, args, id) {
                Ok(answer) => answer,
                Err(why) => {
                    cx.unevaluated(name, &why, *offset);
                    false
                }
            },
        }
    }

    /// usd-core's collection predicate library (`UsdGetCollectionPredicateLibrary`). The
    /// stage holds only defined, non-abstract prims (`def`, active), so `abstract`,
    /// `defined` and `specifier` have fixed answers.
    fn call(&self, name: &str, args: &[Arg], id: PrimId) -> Result<bool, String> {
        let prim = self.stage.prim(id);
        let flag = || args.iter().find(|a| a.name.is_empty()).is_none_or(|a| truthy(&a.value));
        let positional = || args.iter().filter(|a| a.name.is_empty()).map(|a| a.value.as_str());
        let strict = args.iter().find(|a| a.name == "strict").is_some_and(|a| truthy(&a.value));
        match name {
            "abstract" => Ok(!flag()),
            "defined" => Ok(flag()),
            "specifier" => Ok(positional().any(|s| s == "def")),
            "model" => Ok(self.model_flags(id).0 == flag()),
            "group" => Ok(self.model_flags(id).1 == flag()),
            "kind" => {
                let kinds: Vec<&str> = positional().filter(|k| KINDS.iter().any(|(n, _)| n == k)).collect();
                if kinds.is_empty() {
                    return Err("it names no registered kind".into());
                }
                let own = prim.kind.as_deref().unwrap_or("");
                Ok(kinds.iter().any(|k| if strict { own == *k } else { kind_is_a(own, k) }))
            }
            "isa" => {
                let own = prim.type_name.as_deref().unwrap_or("");
                let mut unknown = None;
                for query in positional() {
                    if own == query {
                        return Ok(true);
                    }
                    if strict {
                        continue;
                    }
                    match schema_bases(own) {
                        Some(bases) if bases.contains(&query) => return Ok(true),
                        Some(_) => {}
                        None if !own.is_empty() => unknown = Some(own),
                        None => {}
                    }
                }
                match unknown {
                    Some(t) => Err(format!("strata does not know the schema ancestry of `{t}`")),
                    None => Ok(false),
                }
            }
            "hasAPI" => {
                let instance = args.iter().find(|a| a.name == "instanceName").map(|a| a.value.as_str());
                Ok(positional().any(|api| {
                    prim.api_schemas.iter().any(|s| match s.split_once(':') {
                        Some((base, inst)) => base == api && instance.is_none_or(|i| i == inst),
                        None => s == api && instance.is_none(),
                    })
                }))
            }
            "variant" => {
                if args.iter().any(|a| a.name.is_empty()) {
                    return Err("its arguments must be `set=selection`".into());
                }
                Ok(args.iter().all(|a| {
                    let selection = prim.variant_selections.iter().find(|(s, _)| *s == a.name).map(|(_, v)| v.as_str());
                    glob_matches(&a.value, selection.unwrap_or(""))
                }))
            }
            _ => Err("strata's predicate library has no such function".into()),
        }
    }

    /// `(IsModel, IsGroup)` as `UsdPrim` computes them: a prim is a model when its kind is
    /// a model kind and its parent is a group (or it is a root prim).
    fn model_flags(&self, id: PrimId) -> (bool, bool) {
        let prim = self.stage.prim(id);
        if prim.parent.is_some_and(|p| !self.model_flags(p).1) {
            return (false, false);
        }
        let kind = prim.kind.as_deref().unwrap_or("");
        (kind_is_a(kind, "model"), kind_is_a(kind, "group"))
    }
}

/// The registered kinds and their base kinds (`KindRegistry`).
const KINDS: [(&str, Option<&str>); 5] = [
    ("model", None),
    ("component", Some("model")),
    ("group", Some("model")),
    ("assembly", Some("group")),
    ("subcomponent", None),
];

fn kind_is_a(kind: &str, base: &str) -> bool {
    let mut k = Some(kind);
    while let Some(name) = k {
        if name == base {
            return true;
        }
        k = KINDS.iter().find(|(n, _)| *n == name).and_then(|(_, b)| *b);
    }
    false
}

/// The ancestor schema types of the typed schemas strata renders or names (UsdGeom, UsdLux,
/// UsdShade, UsdVol's `Volume`), nearest first; `None` for a type strata does not know.
fn schema_bases(type_name: &str) -> Option<&'static [&'static str]> {
    const GPRIM: &[&str] = &["Gprim", "Boundable", "Xformable", "Imageable", "Typed"];
    const POINT_BASED: &[&str] = &["PointBased", "Gprim", "Boundable", "Xformable", "Imageable", "Typed"];
    const CURVES: &[&str] = &["Curves", "PointBased", "Gprim", "Boundable", "Xformable", "Imageable", "Typed"];
    const BOUNDABLE_LIGHT: &[&str] = &["BoundableLightBase", "Boundable", "Xformable", "Imageable", "Typed"];
    const NONBOUNDABLE_LIGHT: &[&str] = &["NonboundableLightBase", "Xformable", "Imageable", "Typed"];
    Some(match type_name {
        "Mesh" | "Points" | "TetMesh" => POINT_BASED,
        "BasisCurves" | "NurbsCurves" | "HermiteCurves" => CURVES,
        "Curves" | "NurbsPatch" => &POINT_BASED[1..],
        "PointBased" | "Sphere" | "Cube" | "Cylinder" | "Cylinder_1" | "Cone" | "Capsule" | "Capsule_1" | "Plane"
        | "Volume" => GPRIM,
        "Gprim" | "PointInstancer" => &GPRIM[1..],
        "Boundable" | "Xform" | "Camera" => &GPRIM[2..],
        "Xformable" | "Scope" => &GPRIM[3..],
        "Imageable" | "Material" | "NodeGraph" | "Shader" | "GeomSubset" => &GPRIM[4..],
        "SphereLight" | "RectLight" | "DiskLight" | "CylinderLight" | "PortalLight" => BOUNDABLE_LIGHT,
        "DistantLight" | "DomeLight" | "DomeLight_1" | "GeometryLight" => NONBOUNDABLE_LIGHT,
        "BoundableLightBase" => &BOUNDABLE_LIGHT[1..],
        "NonboundableLightBase" => &NONBOUNDABLE_LIGHT[1..],
        "Typed" => &[],
        _ => return None,
    })
}

/// A predicate argument read as a boolean, as usd-core reads `strict=` and flags.
fn truthy(value: &str) -> bool {
    !matches!(value, "false" | "False" | "0" | "no" | "No" | "n" | "N")
}

/// `path` (absolute, or relative to `anchor` with leading `..`s) made absolute; `None` when
/// `..` climbs above the root. An empty path is the anchor.
fn absolute(anchor: &str, path: &str) -> Option<String> {
    if path.starts_with('/') {
        return Some(path.to_string());
    }
    let mut names: Vec<&str> = anchor.split('/').filter(|s| !s.is_empty()).collect();
    for part in path.split('/').filter(|s| !s.is_empty() && *s != ".") {
        if part == ".." {
            names.pop()?;
        } else {
            names.push(part);
        }
    }
    Some(format!("/{}", names.join("/")))
}

/// Whether `name` matches `glob` (`*` any run, `?` one character, `[abc]`, `[a-z]`,
/// `[!abc]`); an empty glob matches any name.
fn glob_matches(glob: &str, name: &str) -> bool {
    if glob.is_empty() {
        return true;
    }
    let g: Vec<char> = glob.chars().collect();
    let n: Vec<char> = name.chars().collect();
    glob_at(&g, &n)
}

fn glob_at(g: &[char], n: &[char]) -> bool {
    match g.split_first() {
        None => n.is_empty(),
        Some(('*', rest)) => (0..=n.len()).any(|k| glob_at(rest, &n[k..])),
        Some(('?', rest)) => !n.is_empty() && glob_at(rest, &n[1..]),
        Some(('[', rest)) => {
            let Some(close) = rest.iter().skip(1).position(|c| *c == ']').map(|i| i + 1) else {
                return false;
            };
            let Some((&c, tail)) = n.split_first() else { return false };
            let (negate, set) = match rest[..close].split_first() {
                Some(('!' | '^', set)) => (true, set),
                _ => (false, &rest[..close]),
            };
            let mut hit = false;
            let mut i = 0;
            while i < set.len() {
                if i + 2 < set.len() && set[i + 1] == '-' {
                    hit |= (set[i]..=set[i + 2]).contains(&c);
                    i += 3;
                } else {
                    hit |= set[i] == c;
                    i += 1;
                }
            }
            hit != negate && glob_at(&rest[close + 1..], tail)
        }
        Some((c, rest)) => n.first() == Some(c) && glob_at(rest, &n[1..]),
    }
}

struct Parser<'t> {
    text: &'t [u8],
    pos: usize,
}

/// Characters of a prim name or glob: identifier characters (UTF-8 included) and wildcards.
fn name_char(c: u8) -> bool {
    c.is_ascii_alphanumeric() || matches!(c, b'_' | b'*' | b'?') || c >= 0x80
}

impl Parser<'_> {
    fn at_end(&self) -> bool {
        self.pos >= self.text.len()
    }

    fn peek(&self) -> Option<u8> {
        self.text.get(self.pos).copied()
    }

    fn peek_at(&self, ahead: usize) -> Option<u8> {
        self.text.get(self.pos + ahead).copied()
    }

    fn skip_space(&mut self) -> bool {
        let start = self.pos;
        while self.peek().is_some_and(|c| c.is_ascii_whitespace()) {
            self.pos += 1;
        }
        self.pos > start
    }

    fn error(&self, message: impl Into<String>) -> ParseError {
        ParseError { offset: self.pos, message: message.into() }
    }

    /// Skips spaces, then eats `op` if it is next.
    fn operator(&mut self, op: u8) -> bool {
        let save = self.pos;
        self.skip_space();
        if self.peek() == Some(op) {
            self.pos += 1;
            self.skip_space();
            return true;
        }
        self.pos = save;
        false
    }

    fn difference(&mut self) -> Result<Node, ParseError> {
        let mut left = self.intersection()?;
        while self.operator(b'-') {
            left = Node::Difference(Box::new(left), Box::new(self.intersection()?));
        }
        Ok(left)
    }

    fn intersection(&mut self) -> Result<Node, ParseError> {
        let mut left = self.union()?;
        while self.operator(b'&') {
            left = Node::Intersection(Box::new(left), Box::new(self.union()?));
        }
        Ok(left)
    }

    fn union(&mut self) -> Result<Node, ParseError> {
        let mut left = self.implied_union()?;
        while self.operator(b'+') {
            left = Node::Union(Box::new(left), Box::new(self.implied_union()?));
        }
        Ok(left)
    }

    /// Terms separated by whitespace alone.
    fn implied_union(&mut self) -> Result<Node, ParseError> {
        let mut left = self.complement()?;
        loop {
            let save = self.pos;
            if !self.skip_space() || self.peek().is_none_or(|c| matches!(c, b'+' | b'&' | b'-' | b')')) {
                self.pos = save;
                return Ok(left);
            }
            left = Node::Union(Box::new(left), Box::new(self.complement()?));
        }
    }

    fn complement(&mut self) -> Result<Node, ParseError> {
        if self.peek() == Some(b'~') {
            self.pos += 1;
            self.skip_space();
            return Ok(Node::Complement(Box::new(self.atom()?)));
        }
        self.atom()
    }

    fn atom(&mut self) -> Result<Node, ParseError> {
        match self.peek() {
            Some(b'(') => {
                self.pos += 1;
                self.skip_space();
                let inner = self.difference()?;
                self.skip_space();
                if self.peek() != Some(b')') {
                    return Err(self.error("expected `)` to close the group"));
                }
                self.pos += 1;
                Ok(inner)
            }
            Some(b'%') => self.reference(),
            Some(c) if c == b'/' || c == b'.' || c == b'[' || c == b'{' || name_char(c) => {
                Ok(Node::Pattern(self.pattern()?))
            }
            _ => Err(self.error("expected a path pattern, `%` reference, `~` or `(`")),
        }
    }

    /// `%_` or `%path:name`.
    fn reference(&mut self) -> Result<Node, ParseError> {
        let offset = self.pos;
        self.pos += 1;
        if self.peek() == Some(b'_') && self.peek_at(1).is_none_or(|c| !name_char(c) && c != b':' && c != b'/') {
            self.pos += 1;
            return Ok(Node::Weaker);
        }
        let start = self.pos;
        while self.peek().is_some_and(|c| name_char(c) && c != b'*' && c != b'?' || c == b'/' || c == b'.') {
            self.pos += 1;
        }
        let prim = String::from_utf8_lossy(&self.text[start..self.pos]).into_owned();
        if self.peek() != Some(b':') {
            return Err(self.error("expected `:` and a collection name (`%/path:name`), or `%_`"));
        }
        self.pos += 1;
        let name_start = self.pos;
        while self.peek().is_some_and(|c| c.is_ascii_alphanumeric() || c == b'_' || c == b':' || c >= 0x80) {
            self.pos += 1;
        }
        if self.pos == name_start {
            return Err(self.error("expected a collection name after `:`"));
        }
        let name = String::from_utf8_lossy(&self.text[name_start..self.pos]).into_owned();
        Ok(Node::Collection { prim, name, offset })
    }

    fn pattern(&mut self) -> Result<Pattern, ParseError> {
        let absolute = self.peek() == Some(b'/');
        let mut steps = Vec::new();
        let mut property = false;
        let mut expect_element = !absolute;
        loop {
            match self.peek() {
                Some(b'/') if self.peek_at(1) == Some(b'/') => {
                    self.pos += 2;
                    if steps.last() != Some(&Step::AnyDepth) {
                        steps.push(Step::AnyDepth);
                    }
                    expect_element = false;
                    if self.peek() == Some(b'/') {
                        return Err(self.error("expected a name, glob or predicate after `//`"));
                    }
                    continue;
                }
                Some(b'/') => {
                    self.pos += 1;
                    expect_element = true;
                    continue;
                }
                _ => {}
            }
            let element_start = self.peek().is_some_and(|c| name_char(c) || matches!(c, b'[' | b'{' | b'.'));
            if !element_start {
                if expect_element && !(absolute && steps.is_empty()) {
                    return Err(self.error("expected a name, glob or predicate"));
                }
                break;
            }
            if self.peek() == Some(b'.') {
                if self.peek_at(1) == Some(b'.') {
                    if steps.iter().any(|s| *s != Step::Parent) || absolute {
                        return Err(self.error("`..` may only begin a relative pattern"));
                    }
                    self.pos += 2;
                    steps.push(Step::Parent);
                    expect_element = false;
                    continue;
                }
                // `.name`: a property, which no prim matches.
                self.pos += 1;
                let start = self.pos;
                while self.peek().is_some_and(|c| name_char(c) || c == b':' || c == b'[') {
                    if self.peek() == Some(b'[') {
                        self.bracket()?;
                    } else {
                        self.pos += 1;
                    }
                }
                if self.pos == start && self.peek() != Some(b'{') {
                    return Err(self.error("expected a property name after `.`"));
                }
                if self.peek() == Some(b'{') {
                    self.predicate_block()?;
                }
                property = true;
                break;
            }
            let start = self.pos;
            while self.peek().is_some_and(|c| name_char(c) || c == b'[') {
                if self.peek() == Some(b'[') {
                    self.bracket()?;
                } else {
                    self.pos += 1;
                }
            }
            let glob = String::from_utf8_lossy(&self.text[start..self.pos]).into_owned();
            let predicate = if self.peek() == Some(b'{') { Some(self.predicate_block()?) } else { None };
            steps.push(Step::Element { glob, predicate });
            expect_element = false;
            let property_next = self.peek() == Some(b'.') && self.peek_at(1) != Some(b'.');
            if self.peek() != Some(b'/') && !property_next {
                break;
            }
        }
        Ok(Pattern { absolute, steps, property })
    }

    fn bracket(&mut self) -> Result<(), ParseError> {
        self.pos += 1;
        while self.peek().is_some_and(|c| c != b']') {
            self.pos += 1;
        }
        if self.at_end() {
            return Err(self.error("expected `]` to close the character class"));
        }
        self.pos += 1;
        Ok(())
    }

    /// `{ predicate }`.
    fn predicate_block(&mut self) -> Result<Predicate, ParseError> {
        self.pos += 1;
        self.skip_space();
        let pred = self.pred_or()?;
        self.skip_space();
        if self.peek() != Some(b'}') {
            return Err(self.error("expected `}` to close the predicate"));
        }
        self.pos += 1;
        Ok(pred)
    }

    fn keyword(&mut self, word: &str) -> bool {
        let save = self.pos;
        self.skip_space();
        let end = self.pos + word.len();
        if self.text.get(self.pos..end) == Some(word.as_bytes())
            && self.text.get(end).is_none_or(|c| !c.is_ascii_alphanumeric() && *c != b'_')
        {
            self.pos = end;
            self.skip_space();
            return true;
        }
        self.pos = save;
        false
    }

    fn pred_or(&mut self) -> Result<Predicate, ParseError> {
        let mut left = self.pred_and()?;
        while self.keyword("or") {
            left = Predicate::Or(Box::new(left), Box::new(self.pred_and()?));
        }
        Ok(left)
    }

    fn pred_and(&mut self) -> Result<Predicate, ParseError> {
        let mut left = self.pred_implied_and()?;
        while self.keyword("and") {
            left = Predicate::And(Box::new(left), Box::new(self.pred_implied_and()?));
        }
        Ok(left)
    }

    fn pred_implied_and(&mut self) -> Result<Predicate, ParseError> {
        let mut left = self.pred_not()?;
        loop {
            let save = self.pos;
            let spaced = self.skip_space();
            let next_is_term = self.peek().is_some_and(|c| c.is_ascii_alphabetic() || c == b'_' || c == b'(');
            if !spaced || !next_is_term || self.keyword("and") || self.keyword("or") {
                self.pos = save;
                return Ok(left);
            }
            left = Predicate::And(Box::new(left), Box::new(self.pred_not()?));
        }
    }

    fn pred_not(&mut self) -> Result<Predicate, ParseError> {
        if self.keyword("not") {
            return Ok(Predicate::Not(Box::new(self.pred_not()?)));
        }
        if self.peek() == Some(b'(') {
            self.pos += 1;
            self.skip_space();
            let inner = self.pred_or()?;
            self.skip_space();
            if self.peek() != Some(b')') {
                return Err(self.error("expected `)` in the predicate"));
            }
            self.pos += 1;
            return Ok(inner);
        }
        self.call()
    }

    fn identifier(&mut self) -> String {
        let start = self.pos;
        while self.peek().is_some_and(|c| c.is_ascii_alphanumeric() || c == b'_' || c >= 0x80) {
            self.pos += 1;
        }
        String::from_utf8_lossy(&self.text[start..self.pos]).into_owned()
    }

    fn call(&mut self) -> Result<Predicate, ParseError> {
        let offset = self.pos;
        if !self.peek().is_some_and(|c| c.is_ascii_alphabetic() || c == b'_') {
            return Err(self.error("expected a predicate name"));
        }
        let name = self.identifier();
        let mut args = Vec::new();
        match self.peek() {
            Some(b':') => {
                self.pos += 1;
                loop {
                    args.push(Arg { name: String::new(), value: self.value()? });
                    if self.peek() != Some(b',') {
                        break;
                    }
                    self.pos += 1;
                }
            }
            Some(b'(') => {
                self.pos += 1;
                self.skip_space();
                while self.peek() != Some(b')') {
                    let save = self.pos;
                    let key = self.identifier();
                    self.skip_space();
                    let arg = if !key.is_empty() && self.peek() == Some(b'=') {
                        self.pos += 1;
                        self.skip_space();
                        Arg { name: key, value: self.value()? }
                    } else {
                        self.pos = save;
                        Arg { name: String::new(), value: self.value()? }
                    };
                    args.push(arg);
                    self.skip_space();
                    match self.peek() {
                        Some(b',') => {
                            self.pos += 1;
                            self.skip_space();
                        }
                        Some(b')') => {}
                        _ => return Err(self.error("expected `,` or `)` in the argument list")),
                    }
                }
                self.pos += 1;
            }
            _ => {}
        }
        Ok(Predicate::Call { name, args, offset })
    }

    /// A quoted string, or a bare word or number.
    fn value(&mut self) -> Result<String, ParseError> {
        if let Some(q @ (b'"' | b'\'')) = self.peek() {
            let open = self.pos;
            self.pos += 1;
            let start = self.pos;
            while self.peek().is_some_and(|c| c != q) {
                self.pos += 1;
            }
            if self.at_end() {
                return Err(ParseError { offset: open, message: "unterminated string".into() });
            }
            let value = String::from_utf8_lossy(&self.text[start..self.pos]).into_owned();
            self.pos += 1;
            return Ok(value);
        }
        let start = self.pos;
        while self.peek().is_some_and(|c| !c.is_ascii_whitespace() && !matches!(c, b',' | b')' | b'}' | b'(')) {
            self.pos += 1;
        }
        Ok(String::from_utf8_lossy(&self.text[start..self.pos]).into_owned())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn malformed_expressions_say_where() {
        // Offsets agree with usd-core's "at character N" (1-based there).
        for (text, offset) in [("/a +", 4), ("/a &", 4), ("/a/[b", 5), ("~~/a", 1), ("%/W", 3), ("(/a", 3), ("/a/", 3)]
        {
            let err = PathExpression::parse(text).expect_err(text);
            assert_eq!(err.offset, offset, "{text}: {}", err.message);
        }
    }

    #[test]
    fn well_formed_expressions_parse() {
        for text in [
            "/a /b & /c",
            "/a//b*",
            "//{isa:Mesh}",
            "/a/{kind:component}",
            "%_ /a",
            "%/W:c",
            "/a/b*{isa(Mesh, strict=true)}",
            "/a/[bc]x",
            "(/a + /b) & /c",
            "/a/{isa:Mesh and not kind:component}",
            "//",
            "/a//",
            "/a.prop",
            "a/b",
            "../X",
            "/a &/b",
            "{isa:Mesh}",
        ] {
            assert!(PathExpression::parse(text).is_ok(), "{text}: {:?}", PathExpression::parse(text));
        }
    }

    #[test]
    fn operator_precedence_is_usd_cores() {
        // usd-core 0.26: `/a + /b & /c` is `(/a + /b) & /c`, `/b - /b + /a` is `/b - (/b + /a)`.
        let e = PathExpression::parse("/b - /b + /a").expect("parses");
        assert!(matches!(e.root, Node::Difference(_, ref r) if matches!(**r, Node::Union(..))));
        let e = PathExpression::parse("/a + /b & /c").expect("parses");
        assert!(matches!(e.root, Node::Intersection(ref l, _) if matches!(**l, Node::Union(..))));
        let e = PathExpression::parse("/a & /b /c").expect("parses");
        assert!(matches!(e.root, Node::Intersection(_, ref r) if matches!(**r, Node::Union(..))));
    }

    #[test]
    fn globs_match_like_usd() {
        assert!(glob_matches("Ball*", "Ball12"));
        assert!(!glob_matches("Ball*", "ball"));
        assert!(glob_matches("b?ll", "bell"));
        assert!(glob_matches("[bc]x", "cx"));
        assert!(!glob_matches("[!bc]x", "cx"));
        assert!(glob_matches("x[0-9]", "x7"));
        assert!(glob_matches("", "anything"));
    }
}
