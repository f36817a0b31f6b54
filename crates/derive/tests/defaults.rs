//! `#[derive(Defaults)]`: a struct's `Default` from its fields, each field's `#[docs(default =
//! …)]` or its type's own default.

use nerfsv_derive::{Defaults, FieldDocs, ValidateTables};

#[derive(Debug, PartialEq)]
struct Bad(String);

impl Bad {
    fn within(self, table: &str) -> Self {
        Bad(format!("{table}.{}", self.0))
    }
}

#[derive(FieldDocs, Debug, PartialEq)]
struct Camera {
    /// Image width, pixels.
    width: u32,
}

impl Default for Camera {
    fn default() -> Self {
        Camera { width: 64 }
    }
}

impl Camera {
    fn validate(&self) -> Result<(), Bad> {
        match self.width {
            0 => Err(Bad("width".into())),
            _ => Ok(()),
        }
    }
}

#[derive(FieldDocs, ValidateTables, Defaults, Debug, PartialEq)]
#[docs(error = "Bad")]
struct Run {
    /// Scene name.
    #[docs(default = "stonehenge".into())]
    scene: String,
    /// Steps, counted from the scene's own default.
    #[docs(default = 2000)]
    steps: u64,
    /// Unset: the type's default.
    seed: u64,
    /// A table at its type's default.
    #[docs(table)]
    camera: Camera,
    /// A table whose default differs from its type's: both markers on one field.
    #[docs(table)]
    #[docs(default = Camera { width: 8 })]
    preview: Camera,
    /// Both markers in one attribute, in either order.
    #[docs(default = Camera { width: 4 }, table)]
    thumbnail: Camera,
    /// Present only in this crate's tests, default with it.
    #[cfg(test)]
    #[docs(default = 7)]
    probe: u8,
}

#[test]
fn each_field_starts_at_its_own_default_or_its_types() {
    let run = Run::default();
    assert_eq!(run.scene, "stonehenge");
    assert_eq!((run.steps, run.seed), (2000, 0));
    assert_eq!(run.camera, Camera { width: 64 });
    assert_eq!(run.preview, Camera { width: 8 });
    assert_eq!(run.thumbnail, Camera { width: 4 });
    assert_eq!(run.probe, 7);
}

#[test]
fn a_field_with_a_default_is_still_a_table_and_keeps_its_documentation() {
    let mut tables = Vec::new();
    Run::tables("", &mut tables);
    let paths: Vec<&str> = tables.iter().map(|(p, ..)| p.as_str()).collect();
    assert_eq!(paths, ["", "camera", "preview", "thumbnail"]);
    assert_eq!(Run::FIELD_DOCS[1], ("steps", "Steps, counted from the scene's own default."));
    let run = Run { thumbnail: Camera { width: 0 }, ..Run::default() };
    assert_eq!(run.validate_tables(), Err(Bad("thumbnail.width".into())));
}
