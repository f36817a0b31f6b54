//! `#[derive(Choice)]` and `#[derive(FieldDocs)]` on small types.

use nerfsv_derive::{Choice, FieldDocs};

#[derive(Choice, Clone, Copy, Debug, PartialEq, serde::Deserialize)]
enum Estimate {
    Mc,
    CemIs,
    #[serde(rename = "sub")]
    Subset,
}

#[derive(Choice, Clone, Copy, Debug, PartialEq)]
#[choice(what = "sampler label")]
enum Named {
    One,
}

#[test]
fn names_are_kebab_case_unless_serde_renames_them() {
    assert_eq!(Estimate::ALL, [Estimate::Mc, Estimate::CemIs, Estimate::Subset]);
    let names: Vec<&str> = Estimate::ALL.iter().map(|e| e.name()).collect();
    assert_eq!(names, ["mc", "cem-is", "sub"]);
    assert_eq!(Estimate::CemIs.to_string(), "cem-is");
}

#[test]
fn parsing_round_trips_and_names_the_choices_it_refuses() {
    for e in Estimate::ALL {
        assert_eq!(e.name().parse::<Estimate>(), Ok(e));
    }
    assert_eq!("subset".parse::<Estimate>(), Err("unknown estimate \"subset\": one of mc, cem-is, sub".to_owned()));
    assert_eq!("Mc".parse::<Estimate>(), Err("unknown estimate \"Mc\": one of mc, cem-is, sub".to_owned()));
    assert_eq!("two".parse::<Named>(), Err("unknown sampler label \"two\": one of one".to_owned()));
}

/// A camera.
#[derive(FieldDocs)]
#[allow(dead_code)]
struct Camera {
    /// Image width,
    /// pixels ([`u32`]).
    width: u32,
    height: u32,
}

#[test]
fn field_docs_join_lines_and_drop_link_brackets() {
    assert_eq!(Camera::FIELD_DOCS, &[("width", "Image width, pixels (`u32`)."), ("height", "")]);
}
