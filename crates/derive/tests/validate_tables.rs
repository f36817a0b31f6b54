//! `#[derive(ValidateTables)]` on a small config: each table checked by its own `validate`,
//! the first error named `table.key`.

use nerfsv_derive::{FieldDocs, ValidateTables};

/// A refused value: its key (dotted for nested tables) and why.
#[derive(Debug, PartialEq)]
struct Bad {
    key: String,
    why: &'static str,
}

impl Bad {
    fn within(self, table: &str) -> Self {
        Bad { key: format!("{table}.{}", self.key), ..self }
    }
}

#[derive(FieldDocs, Default)]
struct Camera {
    /// Image width, pixels, at least 1.
    width: u32,
}

impl Camera {
    fn validate(&self) -> Result<(), Bad> {
        match self.width {
            0 => Err(Bad { key: "width".into(), why: "must be at least 1" }),
            _ => Ok(()),
        }
    }
}

/// A table checked through a trait rather than an inherent method.
trait Check {
    fn validate(&self) -> Result<(), Bad>;
}

#[derive(FieldDocs, Default)]
struct Light {
    /// Intensity, 0 to 1.
    intensity: f32,
}

impl Check for Light {
    fn validate(&self) -> Result<(), Bad> {
        match (0.0..=1.0).contains(&self.intensity) {
            true => Ok(()),
            false => Err(Bad { key: "intensity".into(), why: "must lie in [0, 1]" }),
        }
    }
}

#[derive(FieldDocs, ValidateTables, Default)]
#[docs(error = "Bad")]
#[allow(dead_code)]
struct Run {
    /// Not marked a table: not checked here, whatever its own `validate` says.
    spare: Camera,
    /// The camera.
    #[docs(table)]
    camera: Camera,
    /// The light, when there is one.
    #[docs(table)]
    light: Option<Light>,
    /// The second light.
    #[docs(table)]
    fill: Light,
}

#[test]
fn every_table_is_checked_in_order_and_its_error_names_table_and_key() {
    let ok =
        Run { spare: Camera { width: 0 }, camera: Camera { width: 4 }, light: None, fill: Light { intensity: 0.5 } };
    assert_eq!(ok.validate_tables(), Ok(()));
    let bad_camera = Run { camera: Camera { width: 0 }, fill: Light { intensity: 2.0 }, ..Run::default() };
    assert_eq!(bad_camera.validate_tables(), Err(Bad { key: "camera.width".into(), why: "must be at least 1" }));
    let bad_fill = Run { camera: Camera { width: 1 }, fill: Light { intensity: 2.0 }, ..Run::default() };
    assert_eq!(bad_fill.validate_tables().unwrap_err().key, "fill.intensity");
    // An optional table is checked when it is set.
    let bad_light = Run { light: Some(Light { intensity: -1.0 }), ..ok };
    assert_eq!(bad_light.validate_tables().unwrap_err().key, "light.intensity");
    assert_eq!(Run::FIELD_DOCS.len(), 4);
}
