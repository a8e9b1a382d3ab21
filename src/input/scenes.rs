//! Scenes and substance files compiled into the binary: the default scene that `strata render`
//! and `strata layers` use when no scene is given. Embedded files live under the virtual
//! directory [`EMBEDDED_DIR`]; file reads consult [`embedded`] before the file system.

use std::path::Path;

/// The virtual directory of embedded files.
pub const EMBEDDED_DIR: &str = "<embedded>";

/// The default scene: (display name, USD text).
pub const DEFAULT_SCENE: (&str, &str) = ("<embedded>/default.usda", include_str!("../../scenes/default/default.usda"));

const FILES: &[(&str, &str)] = &[("default.ash", include_str!("../../scenes/default/default.ash"))];

/// The text of an embedded file, if `path` names one.
pub fn embedded(path: &Path) -> Option<&'static str> {
    let rest = path.strip_prefix(EMBEDDED_DIR).ok()?;
    FILES.iter().find(|(name, _)| Path::new(name) == rest).map(|(_, text)| *text)
}
