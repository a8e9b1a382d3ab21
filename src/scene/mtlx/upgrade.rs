//! MaterialX 1.38's thin-film layering, read as MaterialX's own version upgrade rewrites it
//! (`Document::upgradeVersion`, 1.38 → 1.39; usdMtlx reads every document through it):
//!
//! - a `layer` whose `top` is a `thin_film_bsdf` is bypassed: what read the layer reads its
//!   `base` (through chains of such layers);
//! - every `dielectric_bsdf`, `conductor_bsdf` and `generalized_schlick_bsdf` upstream of that
//!   layer, except a dielectric that only transmits (`scatter_mode` "T"), takes the film's
//!   authored `thickness` and `ior`, values or connections, as its `thinfilm_thickness` and
//!   `thinfilm_ior`.
//!
//! The bypassed layer and the film stay in the translation, unread. MaterialX copies only
//! authored inputs: a film that authors no `thickness` gives the BSDFs none (1.39's default, 0:
//! no film), though 1.38 defaulted it to 550 nm; that, and a film over no BSDF that takes
//! one, are warnings. The rewrite applies whatever the document's version: 1.39 no longer
//! defines `thin_film_bsdf`, so a document that uses it this way means 1.38's film.

use super::{Node, Problem, child_named, connection_of, inputs, tag_range};
use roxmltree::NodeId;
use std::collections::HashMap;

/// The BSDFs that take a film (MaterialX's `BSDF_WITH_THINFILM`).
const TAKES_FILM: &[&str] = &["dielectric_bsdf", "conductor_bsdf", "generalized_schlick_bsdf"];

/// The film's inputs and the BSDF inputs they become.
pub(super) const FILM_INPUTS: [(&str, &str); 2] = [("thickness", "thinfilm_thickness"), ("ior", "thinfilm_ior")];

/// Longest chain of bypassed layers followed (a cycle in a malformed document stops here).
const MAX_CHAIN: usize = 64;

/// The rewrite of one document's thin-film layers.
#[derive(Default)]
pub(super) struct ThinFilmUpgrade<'a, 'i> {
    /// A bypassed layer → the name of the node its readers read instead (its `base`).
    bypassed: HashMap<NodeId, &'a str>,
    /// A BSDF → the film whose inputs it takes (the last in document order, as MaterialX's
    /// in-place rewrite leaves it).
    filmed: HashMap<NodeId, Node<'a, 'i>>,
}

impl<'a, 'i> ThinFilmUpgrade<'a, 'i> {
    /// Finds the thin-film layers of the document under `root`, with warnings for what
    /// MaterialX's upgrade drops.
    pub(super) fn scan(root: Node<'a, 'i>, warnings: &mut Vec<Problem>) -> Self {
        let mut upgrade = Self::default();
        for layer in root.descendants().filter(|n| n.is_element() && n.tag_name().name() == "layer") {
            let Some(scope) = layer.parent_element() else { continue };
            let connected = |input: &str| {
                let input = inputs(layer).find(|i| i.attribute("name") == Some(input))?;
                let name = input.attribute("nodename")?;
                Some((name, child_named(scope, name)?))
            };
            let (Some((_, film)), Some((base, _))) = (connected("top"), connected("base")) else { continue };
            if film.tag_name().name() != "thin_film_bsdf" {
                continue;
            }
            upgrade.bypassed.insert(layer.id(), base);
            let mut reached = 0;
            for bsdf in upstream(layer, scope) {
                let category = bsdf.tag_name().name();
                let scatter = inputs(bsdf).find(|i| i.attribute("name") == Some("scatter_mode"));
                if TAKES_FILM.contains(&category) && scatter.and_then(|s| s.attribute("value")) != Some("T") {
                    upgrade.filmed.insert(bsdf.id(), film);
                    reached += 1;
                }
            }
            let warn = |at: Node, message: String| Problem { range: tag_range(at), message };
            if reached == 0 {
                warnings.push(warn(
                    layer,
                    format!(
                        "the thin film over `{base}` covers no dielectric, conductor or generalized Schlick BSDF: \
                         it is dropped, as MaterialX's upgrade to 1.39 drops it"
                    ),
                ));
            } else if !inputs(film).any(|i| i.attribute("name") == Some("thickness")) {
                warnings.push(warn(
                    film,
                    "`thin_film_bsdf` authors no `thickness`: MaterialX's upgrade to 1.39 carries only authored \
                     inputs, so the BSDFs under it get no film (1.38's default was 550 nm)"
                        .into(),
                ));
            }
        }
        upgrade
    }

    /// The node a `nodename` connection to `name` under `scope` reads: `name`, or for a
    /// bypassed layer the base it stands for.
    pub(super) fn reads(&self, scope: Node<'a, 'i>, mut name: &'a str) -> &'a str {
        for _ in 0..MAX_CHAIN {
            match child_named(scope, name).and_then(|n| self.bypassed.get(&n.id())) {
                Some(base) => name = base,
                None => break,
            }
        }
        name
    }

    /// The film `bsdf` takes its `thinfilm_*` inputs from, if any.
    pub(super) fn film_of(&self, bsdf: Node<'a, 'i>) -> Option<Node<'a, 'i>> {
        self.filmed.get(&bsdf.id()).copied()
    }
}

/// The nodes under `scope` that `node` reads, directly or not, through `nodename` connections
/// (MaterialX's `traverseGraph` within one graph), each once.
fn upstream<'a, 'i>(node: Node<'a, 'i>, scope: Node<'a, 'i>) -> Vec<Node<'a, 'i>> {
    let mut seen = vec![node];
    let mut next = 0;
    while next < seen.len() {
        let at = seen[next];
        next += 1;
        for input in inputs(at) {
            let Some(super::Connection::Node(name, _)) = connection_of(input) else { continue };
            if let Some(source) = child_named(scope, name).filter(|s| !seen.iter().any(|x| x.id() == s.id())) {
                seen.push(source);
            }
        }
    }
    seen.split_off(1)
}
