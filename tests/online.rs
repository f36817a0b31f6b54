//! The online stage measures the stress stage's rollouts without flying them again: each step's
//! uncertainty from the pose the record keeps for the step's end (through its CSV) equals what
//! flying the rollout again with the measurement on gives, bit for bit, for GA and BLA.

mod common;

use nerfsv_pipeline::{RunConfig, Silent};
use nerfsv_scene::Scene;
use nerfsv_sim::{Flight, WorldKind};
use nerfsv_study::flight::{FlightInputs, Mission};
use nerfsv_study::stress::{
    journal_dir, measure_recorded, replay_csv, replay_journal_dir, stress, Flown, OnlineSettings, Sampler, StressSetup,
    IMAGE_LOG_EXTENSION,
};
use nerfsv_study::{KnownRollouts, UqMode};
use nerfsv_uq::Method;
use nerfsv_validation::{parse_csv, write_csv, Label};

/// The drone of the tests' runs: the tiny model's flight over the monolith scene.
fn drone<'a>(inputs: &'a FlightInputs, flight: &'a Flight, scene: &'a Scene, cfg: &'a RunConfig) -> Mission<'a> {
    Mission { drone: cfg.drone(Some(scene)), inputs, flight }
}

/// What a search into `dir/name` wrote: its figures, records (and their CSV bytes), its GT-sim
/// replays' CSV bytes and its folder.
struct Searched {
    figures: nerfsv_study::stress::StressFigures,
    records: Vec<nerfsv_validation::RolloutRecord>,
    bytes: Vec<u8>,
    replays: Vec<u8>,
    out: std::path::PathBuf,
}

fn search(dir: &std::path::Path, name: &str, setup: &StressSetup) -> Searched {
    let out = dir.join(name);
    std::fs::create_dir_all(&out).unwrap();
    let (figures, records) = stress(setup, &out, "k", false, &Silent).unwrap();
    let mut bytes = Vec::new();
    write_csv(&mut bytes, &records).unwrap();
    let replays = std::fs::read(out.join(replay_csv(WorldKind::Gt))).unwrap();
    Searched { figures, records, bytes, replays, out }
}

#[test]
fn measuring_recorded_poses_equals_flying_again_with_the_measurement_on() {
    let dir = tempfile::tempdir().unwrap();
    let (model, field) = common::tiny_model_and_field(dir.path());
    let inputs = FlightInputs::load(&model, &field, Some(&field)).unwrap();
    let text =
        "[sim.vision]\npixels = 16\niterations = 2\nimages_per_step = 2\n[stress]\nseed = 3\n[stress.disturbance]\n\
                std = [0.08, 0.08, 0.04, 0.04, 0.04, 0.04, 0.08, 0.08, 0.08, 0.04, 0.04, 0.04]\n\
                [stress.monte_carlo]\nrollouts = 6\n[uq]\nmax_rays = 16\nperturbations = 1\nlm_iterations = 2\n\
                online_rays = 64\nonline_bla_rays = 16\n";
    let cfg: RunConfig = toml::from_str(text).unwrap();
    let scene = Scene::builtin("monolith").unwrap();
    let prior = cfg.disturbance_prior().unwrap();
    let flight = inputs.plan(&cfg.sim).unwrap();
    for method in [Method::Ga, Method::Bla] {
        let drone = drone(&inputs, &flight, &scene, &cfg);
        let setup = StressSetup {
            replay: false,
            online: Some(OnlineSettings { method, mode: UqMode::Exact, reward: false }),
            ..StressSetup::new(drone, &cfg.stress, &prior, &[Sampler::Mc], &cfg.uq)
        };
        let out = dir.path().join(method.name());
        std::fs::create_dir_all(&out).unwrap();
        let (_, flown) = stress(&setup, &out, "k", false, &Silent).unwrap();
        assert_eq!(flown.len(), 6);
        assert!(flown.iter().any(|r| r.collision_step.is_some()), "the wide prior should crash the drone");
        // Through the CSV, as the online stage reads the stress stage's rollouts, measurement off.
        let mut bytes = Vec::new();
        write_csv(&mut bytes, &flown).unwrap();
        let mut recorded = parse_csv(std::str::from_utf8(&bytes).unwrap()).unwrap();
        recorded.iter_mut().for_each(|r| r.step_uncertainty.clear());
        let (measured, views, _) = measure_recorded(&setup, recorded, &Silent).unwrap();
        let steps_flown: usize = flown.iter().map(|r| r.step_scores.iter().filter(|s| !s.is_nan()).count()).sum();
        assert_eq!(views, steps_flown, "{}: one view per flown step", method.name());
        for (a, b) in flown.iter().zip(&measured) {
            assert_eq!(a.step_uncertainty.len(), 6);
            let bits = |r: &nerfsv_validation::RolloutRecord| {
                r.step_uncertainty.iter().map(|u| u.to_bits()).collect::<Vec<_>>()
            };
            assert_eq!(
                bits(a),
                bits(b),
                "{} rollout {}: {:?} vs {:?}",
                method.name(),
                a.index,
                a.step_uncertainty,
                b.step_uncertainty
            );
        }
        // A record without poses cannot be measured.
        let mut bare = flown[0].clone();
        bare.step_attitudes.clear();
        let e = measure_recorded(&setup, vec![bare], &Silent).unwrap_err().to_string();
        assert!(e.contains("keeps no pose per step"), "{e}");
    }
}

/// The online stage's rewarded CEM takes its first population from the stress stage's CEM (the
/// same seeds, drawn from the prior), and their GT-sim replays from the stress stage's replays:
/// with those given as flown before, it writes the same records and replays bit for bit and
/// flies neither again (its journals lack them).
#[test]
fn a_rewarded_cem_takes_its_first_population_and_its_replays_from_rollouts_flown_before() {
    let dir = tempfile::tempdir().unwrap();
    let (model, field) = common::tiny_model_and_field(dir.path());
    let inputs = FlightInputs::load(&model, &field, Some(&field)).unwrap();
    let text = "[sim.vision]\npixels = 16\niterations = 2\nimages_per_step = 2\n[stress]\nseed = 5\n\
                [stress.cem]\nm = 4\nm_elite = 2\nk_max = 2\nis_samples = 1\n[uq]\nonline_rays = 64\n";
    let cfg: RunConfig = toml::from_str(text).unwrap();
    let scene = Scene::builtin("monolith").unwrap();
    let prior = cfg.disturbance_prior().unwrap();
    let flight = inputs.plan(&cfg.sim).unwrap();
    let drone = drone(&inputs, &flight, &scene, &cfg);
    let setup = |reward: bool| StressSetup {
        online: Some(OnlineSettings { method: Method::Ga, mode: UqMode::Exact, reward }),
        ..StressSetup::new(drone, &cfg.stress, &prior, &[Sampler::Cem], &cfg.uq)
    };
    // The journal's rollout files (each rollout's image log beside it, `….images.csv`, not
    // counted).
    let csv_files = |journal: &std::path::Path| {
        let paths: Vec<_> = std::fs::read_dir(journal).unwrap().map(|e| e.unwrap().path()).collect();
        let logs = paths.iter().filter(|p| p.to_string_lossy().ends_with(".images.csv")).count();
        let rollouts = paths.iter().filter(|p| nerfsv_validation::Journal::is_entry(p)).count();
        assert_eq!(logs, rollouts, "an image log beside each rollout");
        rollouts
    };
    struct Ran {
        records: Vec<nerfsv_validation::RolloutRecord>,
        bytes: Vec<u8>,
        replays: Vec<u8>,
        flown: usize,
        replayed: usize,
        out: std::path::PathBuf,
    }
    let run = |name: &str, setup: &StressSetup| {
        let Searched { records, bytes, replays, out, .. } = search(dir.path(), name, setup);
        let flown = csv_files(&journal_dir(&out, WorldKind::Nerf));
        let replayed = csv_files(&replay_journal_dir(&out, WorldKind::Gt));
        Ran { records, bytes, replays, flown, replayed, out }
    };
    // The plain search flies and replays the first population; the rewarded one, alone and with
    // them given.
    let plain = run("plain", &setup(false));
    let alone = run("alone", &setup(true));
    let first: Vec<_> =
        plain.records.iter().filter(|r| r.sampler == Label::Cem && r.population == 0).cloned().collect();
    assert_eq!(first.len(), 4);
    let plain_replays = parse_csv(std::str::from_utf8(&plain.replays).unwrap()).unwrap();
    let first_replays: Vec<_> = plain_replays.iter().filter(|r| r.population == 0).cloned().collect();
    assert_eq!(first_replays.len(), 4);
    let (plain_journal, plain_replay_journal) =
        (journal_dir(&plain.out, WorldKind::Nerf), replay_journal_dir(&plain.out, WorldKind::Gt));
    let given = StressSetup {
        flown: Some(Flown { records: &first, journal: &plain_journal }),
        replayed: Some(Flown { records: &first_replays, journal: &plain_replay_journal }),
        ..setup(true)
    };
    let reused = run("reused", &given);
    assert_eq!(alone.bytes, reused.bytes, "the same records bit for bit");
    assert_eq!(alone.replays, reused.replays, "the same replays bit for bit");
    assert_eq!(alone.flown, reused.flown + 4, "the first population is not flown again");
    assert_eq!(alone.replayed, reused.replayed + 4, "nor replayed again");
}

/// A second method's rewarded CEM takes the rollouts and replays an earlier method's search flew
/// with the same seeds and disturbances (both draw the first population from the prior, and rank
/// alike while no population holds more failures than elites): it writes what flying them gives,
/// bit for bit, each step measured by its own method, and flies fewer.
#[test]
fn a_second_methods_rewarded_cem_takes_the_first_methods_rollouts_and_writes_the_same() {
    let dir = tempfile::tempdir().unwrap();
    let (model, field) = common::tiny_model_and_field(dir.path());
    let inputs = FlightInputs::load(&model, &field, Some(&field)).unwrap();
    let text = "[sim.vision]\npixels = 16\niterations = 2\nimages_per_step = 2\n[stress]\nseed = 5\n\
                [stress.cem]\nm = 4\nm_elite = 2\nk_max = 2\nis_samples = 1\n[uq]\nonline_rays = 64\n\
                online_bla_rays = 16\nperturbations = 1\nlm_iterations = 2\nmax_rays = 16\n";
    let cfg: RunConfig = toml::from_str(text).unwrap();
    let scene = Scene::builtin("monolith").unwrap();
    let prior = cfg.disturbance_prior().unwrap();
    let flight = inputs.plan(&cfg.sim).unwrap();
    let drone = drone(&inputs, &flight, &scene, &cfg);
    let setup = |method: Method| StressSetup {
        online: Some(OnlineSettings { method, mode: UqMode::Exact, reward: true }),
        ..StressSetup::new(drone, &cfg.stress, &prior, &[Sampler::Cem], &cfg.uq)
    };
    let run = |name: &str, setup: &StressSetup| {
        let Searched { figures, records, bytes, replays, out } = search(dir.path(), name, setup);
        (figures, records, bytes, replays, out)
    };
    let (_, ga, _, ga_replays, ga_out) = run("ga", &setup(Method::Ga));
    let (_, _, alone, alone_replays, _) = run("bla_alone", &setup(Method::Bla));
    let mut known = KnownRollouts::default();
    known.from_journal(&ga, &journal_dir(&ga_out, WorldKind::Nerf), IMAGE_LOG_EXTENSION);
    let ga_replays = parse_csv(std::str::from_utf8(&ga_replays).unwrap()).unwrap();
    let mut known_replays = KnownRollouts::default();
    known_replays.from_journal(&ga_replays, &replay_journal_dir(&ga_out, WorldKind::Gt), IMAGE_LOG_EXTENSION);
    assert_eq!((known.len(), known_replays.len()), (9, 8), "every rollout and replay GA flew");
    let given = StressSetup { known: Some(&known), known_replays: Some(&known_replays), ..setup(Method::Bla) };
    let (figures, records, taking, taking_replays, _) = run("bla_taking", &given);
    assert_eq!(alone, taking, "the same records bit for bit");
    assert_eq!(alone_replays, taking_replays, "the same replays bit for bit");
    assert!(known.taken() >= 4 && known_replays.taken() >= 4, "{} {}", known.taken(), known_replays.taken());
    assert!(records.iter().any(|r| r.step_uncertainty.iter().any(|u| u.is_finite())));
    // Its steps are BLA's, not GA's.
    assert_ne!(records[0].step_uncertainty, ga[0].step_uncertainty);
    assert_eq!(figures.rollouts, 9 + 8);
}
