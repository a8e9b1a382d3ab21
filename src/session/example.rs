//! The default scene written out for editing: what the update tests and `strata bench update`
//! change, as a live view's user would.

use std::path::{Path, PathBuf};

/// Writes the default scene into `dir` with its substances split over two files — `dirt.ash`
/// holds the dirt substance and the node type only it uses, `default.ash` the others — so a
/// change to one file touches only some compositions. Returns the scene's path.
pub fn write_split_default_scene(dir: &Path) -> std::io::Result<PathBuf> {
    let usda = crate::input::scenes::DEFAULT_SCENE.1;
    let ash = crate::input::scenes::embedded(&Path::new(crate::input::scenes::EMBEDDED_DIR).join("default.ash"))
        .ok_or_else(|| std::io::Error::other("the default scene's substance file is not embedded"))?;
    let find = |what: &str, text: &str| {
        text.find(what).ok_or_else(|| std::io::Error::other(format!("the default scene has no `{what}`")))
    };
    let (threshold, clay) = (find("shader threshold(", ash)?, find("substance clay", ash)?);
    let (dirt, red) = (find("substance dirt {", ash)?, find("override red_paint", ash)?);
    std::fs::write(dir.join("dirt.ash"), format!("{}{}", &ash[threshold..clay], &ash[dirt..red]))?;
    std::fs::write(dir.join("default.ash"), format!("{}{}{}", &ash[..threshold], &ash[clay..dirt], &ash[red..]))?;
    let at = find("def Material \"Dirt\"", usda)?;
    let usda = format!("{}{}", &usda[..at], usda[at..].replacen("@default.ash@", "@dirt.ash@", 1));
    let path = dir.join("default.usda");
    std::fs::write(&path, usda)?;
    Ok(path)
}
