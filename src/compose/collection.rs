//! UsdCollectionAPI membership, as far as binding needs it: which prims a collection holds.
//! Shared by UsdShade's collection-based `material:binding` and strata's collection-based
//! slot bindings (DESIGN.md rule 1c), so both resolve membership the same way.

use crate::scene::{Prim, Value as UsdValue};
use std::collections::HashSet;

/// A collection's membership rules: includes, excludes, expansion rule and `includeRoot`.
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
    /// `collection:NAME:membershipExpression` is authored (strata does not evaluate path
    /// expressions; the caller reports it).
    pub has_expression: bool,
}

impl Collection {
    /// Reads collection `name` of `owner` (`collection:NAME:includes`, `excludes`,
    /// `expansionRule`, `includeRoot`).
    pub fn read(owner: &Prim, name: &str) -> Collection {
        let paths = |rel: &str| -> HashSet<String> {
            owner
                .relationship(&format!("collection:{name}:{rel}"))
                .map(|r| r.targets.iter().map(|(p, _)| p.clone()).collect())
                .unwrap_or_default()
        };
        Collection {
            includes: paths("includes"),
            excludes: paths("excludes"),
            explicit_only: owner.value(&format!("collection:{name}:expansionRule")).and_then(UsdValue::as_str)
                == Some("explicitOnly"),
            include_root: matches!(owner.value(&format!("collection:{name}:includeRoot")), Some(UsdValue::Bool(true))),
            has_expression: owner.value(&format!("collection:{name}:membershipExpression")).is_some(),
        }
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
