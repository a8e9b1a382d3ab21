//! Slot-name lints (issue 23), each a rendered-diagnostic snapshot of `strata check` on a
//! scene in `tests/in/lints/` plus a scene that must not warn. The lints are warnings: the
//! scene still checks clean of errors.

use std::path::Path;
use strata::session::check_file;

/// The rendered warnings `strata check` gives for `tests/in/lints/NAME.usda`.
fn warnings(name: &str) -> String {
    let path = format!("tests/in/lints/{name}.usda");
    let (diags, sources, _) = check_file(Path::new(&path));
    let text = diags.render(&sources);
    assert!(!diags.has_errors(), "{path}: lints are warnings, not errors:\n{text}");
    text
}

macro_rules! lint_snapshots {
    ($($name:ident => $file:literal, $says:literal),* $(,)?) => {
        $(
            #[test]
            fn $name() {
                let text = warnings($file);
                assert!(text.contains($says), "{text}");
                assert!(text.contains(concat!("tests/in/lints/", $file, ".usda:")), "located: {text}");
                insta::assert_snapshot!(stringify!($name), text);
            }
        )*
    };
}

lint_snapshots! {
    numeric_names_of_different_lengths => "numeric", "slot name `9` sorts above `10` by byte order",
    look_alike_names => "look_alike", "slot name `O50` differs from `050` only by case or look-alike characters",
    base_slot_never_bound => "unbound_base", "override slot `050::010` attaches to slot `050`, which is never bound",
    hidden_on_every_prim => "hidden", "slot `000` is hidden on every prim it reaches",
    no_surface_and_no_displacement => "no_surface", "has no surface and no displacement",
}

#[test]
fn well_named_slots_do_not_warn() {
    for name in ["clean", "numeric_ok"] {
        assert_eq!(warnings(name), "", "{name}");
    }
}

#[test]
fn look_alike_keys_fold_case_and_confusable_characters() {
    // `01O` is `010`; `Dirt` and `dirt` are one name too; `050` and `060` are not.
    let text = warnings("look_alike");
    assert!(text.contains("slot name `01O` differs from `010`"), "{text}");
    assert!(!text.contains("`060`"), "{text}");
}
