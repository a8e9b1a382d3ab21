//! UsdCollectionAPI membership, as far as binding needs it: which prims a collection holds.
//! Shared by UsdShade's collection-based `material:binding` and strata's collection-based
//! slot bindings (DESIGN.md rule 1c), so both resolve membership the same way.
//!
//! As usd-core's `ComputeMembershipQuery`: a collection with `includes` or `excludes` targets,
//! or `includeRoot`, is read from those; otherwise its `membershipExpression` (a USD path
//! expression, [`super::path_expression`]) decides, and matches exactly the prims it names
//! (the expansion rule does not widen an expression's matches).

use super::path_expression::{Context, Matcher, PathExpression};
use crate::diag::{Diagnostic, Diagnostics, Span};
use crate::scene::{Attribute, Prim, PrimId, Stage, Value as UsdValue};
use std::collections::{HashMap, HashSet};

/// A collection's membership rules: includes, excludes, expansion rule and `includeRoot`,
/// or the prims its membership expression matches.
#[derive(Clone, Debug, Default)]
pub struct Collection {
    /// `collection:NAME:includes` targets.
    pub includes: HashSet<String>,
    /// `collection:NAME:excludes` targets.
    pub excludes: HashSet<String>,
    /// `expansionRule = "explicitOnly"`: only the included paths themselves.
    pub explicit_only: bool,
    /// `includeRoot`: the pseudo-root's descendants, i.e. everything not excluded.
    pub include_root: bool,
    /// When the collection is expression-based: the paths of the prims its
    /// `membershipExpression` matches.
    pub expression_members: Option<HashSet<String>>,
}

impl Collection {
    /// Reads collection `name` of `owner` (`collection:NAME:includes`, `excludes`,
    /// `expansionRule`, `includeRoot`, `membershipExpression`), evaluating a membership
    /// expression over `stage`. Malformed expressions are errors at their file:line:col;
    /// predicates strata cannot evaluate and references to missing or cyclic collections are
    /// warnings (they match nothing).
    pub fn read(stage: &Stage, owner: &Prim, name: &str, diags: &mut Diagnostics) -> Collection {
        read_guarded(stage, owner, name, diags, &mut Vec::new())
    }

    /// Whether `owner` defines collection `name`: applies `CollectionAPI:NAME` or authors one
    /// of its properties.
    pub fn exists(owner: &Prim, name: &str) -> bool {
        let prefix = format!("collection:{name}:");
        owner.api_schemas.iter().any(|s| s.strip_prefix("CollectionAPI:") == Some(name))
            || owner.attributes.iter().any(|a| a.name.starts_with(&prefix))
            || owner.relationships.iter().any(|r| r.name.starts_with(&prefix))
    }

    /// Whether `path` is a member: with `expandPrims`, the closest of its ancestors (itself
    /// included) that the collection names decides, an exclude beating an include.
    pub fn contains(&self, path: &str) -> bool {
        if let Some(members) = &self.expression_members {
            return members.contains(path);
        }
        if self.explicit_only {
            return self.includes.contains(path) && !self.excludes.contains(path);
        }
        let mut p = path;
        loop {
            if self.excludes.contains(p) {
                return false;
            }
            if self.includes.contains(p) {
                return true;
            }
            match p.rsplit_once('/') {
                Some(("", _)) | None => return self.include_root && !self.excludes.contains("/"),
                Some((parent, _)) => p = parent,
            }
        }
    }

    /// An included or excluded path that names another collection (`</A.collection:x>`),
    /// which strata does not expand.
    pub fn nested(&self) -> Option<&String> {
        self.includes.iter().chain(&self.excludes).find(|p| p.contains(".collection:"))
    }
}

/// [`Collection::read`], with the collections being read (`/A.collection:x`) on `visiting`
/// so that a reference cycle is reported rather than followed.
fn read_guarded(
    stage: &Stage,
    owner: &Prim,
    name: &str,
    diags: &mut Diagnostics,
    visiting: &mut Vec<String>,
) -> Collection {
    let paths = |rel: &str| -> HashSet<String> {
        owner
            .relationship(&format!("collection:{name}:{rel}"))
            .map(|r| r.targets.iter().map(|(p, _)| p.clone()).collect())
            .unwrap_or_default()
    };
    let mut collection = Collection {
        includes: paths("includes"),
        excludes: paths("excludes"),
        explicit_only: owner.value(&format!("collection:{name}:expansionRule")).and_then(UsdValue::as_str)
            == Some("explicitOnly"),
        include_root: matches!(owner.value(&format!("collection:{name}:includeRoot")), Some(UsdValue::Bool(true))),
        expression_members: None,
    };
    let relationship_mode =
        !collection.includes.is_empty() || !collection.excludes.is_empty() || collection.include_root;
    if !relationship_mode && let Some(attr) = owner.attribute(&format!("collection:{name}:membershipExpression")) {
        collection.expression_members = Some(expression_members(stage, owner, name, attr, diags, visiting));
    }
    collection
}

/// The prims collection `name`'s membership expression `attr` (with its weaker opinions,
/// for `%_`) matches over `stage`.
fn expression_members(
    stage: &Stage,
    owner: &Prim,
    name: &str,
    attr: &Attribute,
    diags: &mut Diagnostics,
    visiting: &mut Vec<String>,
) -> HashSet<String> {
    let mut parsed = Vec::new();
    for (value, span) in attr.value.iter().chain(&attr.weaker_defaults) {
        let text = value.as_str().unwrap_or_default();
        match PathExpression::parse(text) {
            Ok(e) => parsed.push((e, *span, quote_width(text, *span))),
            Err(e) => {
                let at = inside(*span, quote_width(text, *span), e.offset);
                diags.push(
                    Diagnostic::error(format!("malformed path expression in `{}` on `{}`: {}", attr.name, owner.path, e.message))
                        .at(at, "here")
                        .note("USD path expressions: patterns such as `/World//Ball*` or `//{isa:Mesh}`, `%_`, `%/path:collection`, joined by `~`, `+` (or a space), `&`, `-`"),
                );
                // A malformed expression holds nothing (usd-core refuses the layer).
                return HashSet::new();
            }
        }
    }
    let mut members = HashSet::new();
    if parsed.is_empty() {
        return members;
    }
    visiting.push(format!("{}.collection:{name}", owner.path));
    let mut eval = Evaluation {
        stage,
        anchor: &owner.path,
        opinions: &parsed,
        level: 0,
        diags,
        visiting,
        referenced: HashMap::new(),
        unevaluated: HashSet::new(),
    };
    let matcher = Matcher::new(stage, &owner.path);
    for (id, prim) in stage.depth_first() {
        if matcher.matches(&parsed[0].0, id, &mut eval) {
            members.insert(prim.path.clone());
        }
    }
    visiting.pop();
    members
}

/// How many quote characters open a string literal spanning `span` whose text is `text`
/// (1 for `"..."`, 3 for `"""..."""`; escapes may make a column inside it approximate).
fn quote_width(text: &str, span: Span) -> usize {
    let extra = (span.end.saturating_sub(span.start) as usize).saturating_sub(text.len());
    if extra >= 6 { 3 } else { 1 }
}

/// The one-character span at byte `offset` of a string literal's text.
fn inside(literal: Span, quote: usize, offset: usize) -> Span {
    let at = (literal.start as usize + quote + offset).min(literal.end.saturating_sub(1) as usize);
    Span::new(literal.file, at, at + 1)
}

/// Evaluates one collection's expression opinions (strongest first): `%_` at `level` is the
/// next weaker opinion; referenced collections are read once.
struct Evaluation<'a> {
    stage: &'a Stage,
    anchor: &'a str,
    opinions: &'a [(PathExpression, Span, usize)],
    level: usize,
    diags: &'a mut Diagnostics,
    visiting: &'a mut Vec<String>,
    /// Referenced collections' expression members, by `/A.collection:x`.
    referenced: HashMap<String, HashSet<String>>,
    /// Predicate names already reported as unevaluated.
    unevaluated: HashSet<String>,
}

impl Evaluation<'_> {
    fn span_at(&self, offset: usize) -> Span {
        let (_, span, quote) = &self.opinions[self.level];
        inside(*span, *quote, offset)
    }
}

impl Context for Evaluation<'_> {
    fn weaker_includes(&mut self, id: PrimId) -> bool {
        let opinions = self.opinions;
        let Some((weaker, _, _)) = opinions.get(self.level + 1) else { return false };
        self.level += 1;
        let answer = Matcher::new(self.stage, self.anchor).matches(weaker, id, self);
        self.level -= 1;
        answer
    }

    /// As usd-core resolves `%/A:x`: collection `x`'s membership expression stands in its
    /// place (its includes and excludes play no part); one it lacks is empty.
    fn collection_includes(&mut self, owner: &str, name: &str, id: PrimId, offset: usize) -> bool {
        let key = format!("{owner}.collection:{name}");
        if !self.referenced.contains_key(&key) {
            let stage = self.stage;
            let found = stage.find(owner).map(|o| stage.prim(o)).filter(|o| Collection::exists(o, name));
            let members = match found {
                _ if self.visiting.contains(&key) => {
                    let at = self.span_at(offset);
                    self.diags.push(
                        Diagnostic::warning(format!(
                            "path expression references `{key}`, whose expression references it back: the reference holds nothing"
                        ))
                        .at(at, "cyclic reference"),
                    );
                    HashSet::new()
                }
                Some(prim) => match prim.attribute(&format!("collection:{name}:membershipExpression")) {
                    Some(attr) => expression_members(stage, prim, name, attr, self.diags, self.visiting),
                    None => HashSet::new(),
                },
                None => {
                    let at = self.span_at(offset);
                    self.diags.push(
                        Diagnostic::warning(format!(
                            "path expression references the collection `{key}`, which does not exist: it holds nothing"
                        ))
                        .at(at, "no such collection"),
                    );
                    HashSet::new()
                }
            };
            self.referenced.insert(key.clone(), members);
        }
        self.referenced[&key].contains(&self.stage.prim(id).path)
    }

    fn unevaluated(&mut self, predicate: &str, why: &str, offset: usize) {
        // One warning per predicate name, at its first use.
        if !self.unevaluated.insert(predicate.to_string()) {
            return;
        }
        let at = self.span_at(offset);
        self.diags.push(
            Diagnostic::warning(format!(
                "strata cannot evaluate the path-expression predicate `{predicate}` ({why}); prims are treated as not matching it"
            ))
            .at(at, "this predicate"),
        );
    }
}
