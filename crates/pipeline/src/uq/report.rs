//! The offline uncertainty stage's section of the report.
//!
//! Presentation only: a stage's key digests its own module file, not this child module, so a
//! change here redoes no stage.

use std::path::Path;

use crate::report::{num, Section, Table};
use crate::uq::{UqFigures, UqStage};
use crate::{Report, ReportContext, Stage};
use nerfsv_uq::offline::{figure_stems, short, MAPS_PNG};
use nerfsv_uq::Method;

impl Report for UqStage<'_> {
    const ABOUT: &'static str = "offline uncertainty: GA, BLA, depth AUSE";

    fn describe(f: &UqFigures) -> String {
        let splits = [&f.train, &f.val, &f.test];
        let ga: usize = splits.iter().map(|s| s.ga_images).sum();
        let bla: usize = splits.iter().map(|s| s.bla_images).sum();
        format!(
            "GA on {ga} images (test mean σ_d {}), BLA on {bla} (test mean trace {}); depth AUSE GA {} over {}, BLA {} over {}; {:.1} s",
            short(f.test.ga_mean_sigma_d),
            short(f.test.bla_mean_normalized_trace),
            short(f.ause_ga),
            f.ause_ga_images,
            short(f.ause_bla),
            f.ause_bla_images,
            f.seconds
        )
    }

    fn report(u: &UqFigures, _: &ReportContext) -> Option<Section> {
        let mut s =
            Section::new(UqStage::NAME, "Offline uncertainty per image, and its calibration", "offline uncertainty");
        let t = &u.test;
        s.answer(
            40,
            format!(
                "<b>How far can the NeRF be trusted?</b> On its test images GA's noise-floored σ_d has median {} (the \
                 paper's σ_d: {}, {} of {} images excluded at σ_d ≥ 3); BLA's information gain averages {} nats; depth \
                 AUSE GA {}, BLA {} (lower ranks errors better).",
                num(t.ga_floored_median_sigma_d, 3),
                num(t.ga_median_sigma_d, 2),
                t.ga_excluded,
                t.ga_images,
                num(t.bla_mean_information_gain, 1),
                num(u.ause_ga, 3),
                num(u.ause_bla, 3),
            ),
        );
        split_tables(&mut s, u);
        ause_tables(&mut s, u);
        s.paragraph(
            "Depth AUSE protocol: every test pixel with a ground-truth depth counts; a pixel whose ray composites \
             no sample has no uncertainty and ranks as the most uncertain (removed first), not dropped. Bayes' Rays \
             score only the pixels their method gives a value, so where many pixels are unscored the figures are not \
             directly comparable (ause.csv counts them per image).",
        );
        let captions = [
            "GA: σ_d per image and split",
            "GA: μ_d against σ_d",
            "BLA: normalised trace per image and split",
            "BLA: rmv per image and split",
            "BLA: normalised trace against rmv",
        ];
        let stems = [Method::Ga, Method::Bla].into_iter().flat_map(figure_stems);
        if u.maps_drawn {
            s.picture(
                MAPS_PNG,
                "Per pixel, on one test view: the NeRF's depth error and GA's and BLA's depth standard deviations \
                 (and the ensemble's, with one)",
            );
        }
        for (stem, caption) in stems.zip(captions) {
            s.picture(&format!("{stem}.png"), caption);
        }
        if u.ensemble_field.is_some() {
            let slice = nerfsv_uq::offline::field_slice_path(Path::new(UqStage::ENSEMBLE_FIELD));
            s.picture(
                &slice.to_string_lossy(),
                &format!(
                    "The ensemble's uncertainty field at z = {:.2} m: the members' density standard deviation ({}, with `nerfsv uq field --method ensemble`'s format)",
                    nerfsv_uq::offline::FIELD_SLICE_ALTITUDE,
                    UqStage::ENSEMBLE_FIELD
                ),
            );
        }
        s.csv(UqStage::AUSE_CSV, "ause.csv");
        s.csv(UqStage::GA_CSV, "uq_ga.csv");
        s.csv(UqStage::BLA_CSV, "uq_bla.csv");
        Some(s)
    }
}

/// GA's and BLA's figures per split, and what they mean.
fn split_tables(s: &mut Section, u: &UqFigures) {
    let splits = [("train", &u.train), ("val", &u.val), ("test", &u.test)];
    s.table(
        Table::new(&[
            "split",
            "GA images",
            "excluded (σ_d ≥ 3)",
            "mean σ_d",
            "median σ_d",
            "noise-floored: excluded (≥ 3)",
            "mean σ_d",
            "median σ_d",
        ])
        .rows(splits.iter().map(|(name, x)| {
            vec![
                name.to_string(),
                x.ga_images.to_string(),
                x.ga_excluded.to_string(),
                num(x.ga_mean_sigma_d, 3),
                num(x.ga_median_sigma_d, 3),
                x.ga_floored_excluded.to_string(),
                num(x.ga_floored_mean_sigma_d, 3),
                num(x.ga_floored_median_sigma_d, 3),
            ]
        })),
    );
    s.table(
        Table::new(&["split", "BLA images", "mean normalised trace", "mean rmv", "mean information gain (nats)"]).rows(
            splits.iter().map(|(name, x)| {
                vec![
                    name.to_string(),
                    x.bla_images.to_string(),
                    num(x.bla_mean_normalized_trace, 4),
                    num(x.bla_mean_rmv, 4),
                    num(x.bla_mean_information_gain, 1),
                ]
            }),
        ),
    );
    s.paragraph(
        "GA's σ_d is the paper's eq. 2, which has no pixel-noise term: a nearly transparent ray (tiny \
         s = Σ c²d²) turns any noise in its colour into a huge (r − μm)²/s and drives σ_d, which is why the \
         paper's σ_d ≥ 3 exclusion removes many images. The noise-floored σ_d fits r ~ N(μm, σ_d²s + σ_n²) with \
         σ_n the pixel noise (uq.noise_std): 0 when the model explains the image up to its noise; it is shown \
         beside the paper's, and the online measure and reward use it by default (uq.ga_measure). GA's \
         per-pixel maps keep the paper's σ_d: a map is σ_d times a per-pixel factor, so its ranking, which the \
         AUSE measures, does not depend on it. Over the white background, colours are taken relative to it \
         (c − bg, r = reference − bg): scaling the weights by μ scales the opacity too, so μ = 0.8 is exactly the \
         render with every weight scaled by 0.8 (the paper writes eq. 2 without a background).",
    );
    s.paragraph(
        "BLA's prior is centred at the trained weights. The normalised trace tr(Σ)/P and rmv are the \
         paper's (its eq. 11 reward uses their product); in the directions an image's rays do not see, Σ is the \
         prior's 1/α, so with m residuals and P weights the trace cannot fall below (P − m)/(P·α): it mostly \
         measures the prior. The information gain ½ Σ<sub>k</sub> ln(1 + e<sub>k</sub>/(σ<sub>n</sub>²α)) \
         counts only the data's directions: 0 for an image that constrains nothing.",
    );
}

/// The depth AUSE of every method, against the ensemble's and a random order's.
fn ause_tables(s: &mut Section, u: &UqFigures) {
    s.table(Table::new(&["method", "test images", "depth AUSE (0 is perfect)"]).rows([
        vec!["GA".into(), u.ause_ga_images.to_string(), num(u.ause_ga, 3)],
        vec!["BLA".into(), u.ause_bla_images.to_string(), num(u.ause_bla, 3)],
    ]));
    if let Some(e) = &u.ensemble_ause {
        s.paragraph(format!(
            "The ensemble ({} NeRFs) ranks the deployed model's depth error by the members' depth standard \
             deviation; a random ordering of the same errors is the baseline any uncertainty must beat. On the \
             same test images as each method:",
            e.members
        ));
        let rows = [
            ("GA's", e.ga_images, u.ause_ga, e.on_ga_images, e.random_on_ga_images),
            ("BLA's", e.bla_images, u.ause_bla, e.on_bla_images, e.random_on_bla_images),
        ];
        s.table(Table::new(&["images", "images scored", "method's depth AUSE", "ensemble", "random order"]).rows(
            rows.map(|(name, n, method, ensemble, random)| {
                vec![name.into(), n.to_string(), num(method, 3), num(ensemble, 3), num(random, 3)]
            }),
        ));
    }
    if let Some(c) = &u.ause_on_common_images {
        s.paragraph(format!(
            "Every method on the same {} test images (those all of them scored), mean ± bootstrap standard error \
             over the images. A perfect ranking scores 0 (the oracle's); the oracle's own curve encloses {} on \
             these images, the scale to read an AUSE against; a random order of the same errors is the baseline \
             an uncertainty must beat.",
            c.images,
            num(c.oracle_area, 3)
        ));
        s.table(
            Table::new(&["method", "depth AUSE", "± SE"])
                .rows(c.methods.iter().map(|m| vec![m.method.to_uppercase(), num(m.mean, 3), num(m.bootstrap_se, 3)])),
        );
    }
}
