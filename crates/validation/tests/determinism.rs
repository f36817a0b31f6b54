//! Same seed, same bytes — at any thread count; and any recorded rollout replays from its seed.

mod common;

use common::{LinearToy, Z_1E3};
use nerfsv_validation::{
    cross_entropy, monte_carlo, replay, rollout_seed, write_csv, CemConfig, Label, MonteCarloConfig, RolloutRecord,
};

/// A reward in the shape of the paper's eq. 10 (log-likelihood minus a penalty), depending on
/// the record's scores and index too, to exercise the hook.
fn reward(r: &RolloutRecord) -> f64 {
    r.log_p - 36.0 * r.step_scores.iter().sum::<f64>() - 1e-3 * r.index as f64
}

/// MC and CEM (with a reward) on the toy, as CSV bytes, in a pool of `threads` threads.
fn csv_bytes(threads: usize, seed: u64) -> Vec<u8> {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
    pool.install(|| {
        let toy = LinearToy::new(2.0);
        let prior = toy.prior();
        let mc = monte_carlo(&toy, &prior, &MonteCarloConfig { rollouts: 200 }, seed, &()).unwrap();
        let cfg = CemConfig { m: 40, m_elite: 8, k_max: 3, is_samples: 50, ..CemConfig::default() };
        let cem = cross_entropy(&toy, &prior, &cfg, seed, Some(&reward), &()).unwrap();
        let mut out = Vec::new();
        let all: Vec<RolloutRecord> = mc.records.into_iter().chain(cem.records).collect();
        write_csv(&mut out, &all).unwrap();
        out
    })
}

#[test]
fn same_seed_gives_byte_identical_csv_with_one_and_two_threads() {
    let one = csv_bytes(1, 42);
    let two = csv_bytes(2, 42);
    assert!(one == two, "CSV differs between 1 and 2 threads");
    // ... and the seed matters.
    assert!(csv_bytes(2, 43) != one, "a different run seed gave the same CSV");
    let text = String::from_utf8(one).unwrap();
    let mut lines = text.lines();
    assert_eq!(
        lines.next().unwrap(),
        "sampler,population,index,seed,step,d0,d1,log_p,log_q,uncertainty,reward,score,trajectory_log_q,clearance,x,y,z,rx,ry,rz,collided,lost,counted,defensive_fraction"
    );
    // (200 MC + 3·40 CEM + 50 IS) rollouts × 6 steps.
    assert_eq!(lines.count(), (200 + 120 + 50) * 6);
    let first: Vec<&str> = text.lines().nth(1).unwrap().split(',').collect();
    assert_eq!(first[..5], ["mc", "0", "0", &rollout_seed(42, "mc", 0, 0).to_string(), "0"]);
}

#[test]
fn a_recorded_rollout_replays_from_its_seed() {
    let toy = LinearToy::new(2.0);
    let prior = toy.prior();
    let cfg = CemConfig { m: 40, m_elite: 8, k_max: 3, is_samples: 50, ..CemConfig::default() };
    let cem = cross_entropy(&toy, &prior, &cfg, 7, Some(&reward), &()).unwrap();
    let mc = monte_carlo(&toy, &prior, &MonteCarloConfig { rollouts: 30 }, 7, &()).unwrap();
    let picks = [
        cem.records.iter().find(|r| r.sampler == Label::Cem && r.population == 2 && r.index == 13).unwrap(),
        cem.records.iter().find(|r| r.sampler == Label::CemIs && r.index == 31).unwrap(),
    ];
    for rec in picks {
        assert_eq!(rec.seed, rollout_seed(7, rec.sampler.name(), rec.population, rec.index));
        let again = replay(
            &toy,
            &prior,
            cem.proposal_of(rec),
            rec,
            if rec.sampler == Label::Cem { Some(&reward) } else { None },
        );
        assert_eq!(&again, rec, "{} {}/{} did not replay", rec.sampler, rec.population, rec.index);
        // The system's own randomness follows the seed too: another seed, other step scores.
        let other = RolloutRecord { seed: rec.seed ^ 1, ..rec.clone() };
        let moved = replay(&toy, &prior, cem.proposal_of(rec), &other, None);
        assert_ne!(moved.disturbances, rec.disturbances);
    }
    let rec = &mc.records[17];
    assert_eq!(&replay(&toy, &prior, &prior.to_proposal(), rec, None), rec);
    // Records survive a JSON round trip unchanged.
    let json = serde_json::to_string(rec).unwrap();
    assert_eq!(&serde_json::from_str::<RolloutRecord>(&json).unwrap(), rec);
}

#[test]
fn csv_file_is_written_atomically_matches_the_stream_and_reads_back_bit_for_bit() {
    let toy = LinearToy::new(Z_1E3);
    let mut mc = monte_carlo(&toy, &toy.prior(), &MonteCarloConfig { rollouts: 5 }, 1, &()).unwrap();
    // Positions, uncertainties, rewards and non-finite clearances survive too.
    mc.records[1].step_positions = (0..6).map(|t| [t as f64, -0.1 / 3.0, 1e-300]).collect();
    mc.records[1].step_attitudes = (0..6).map(|t| [-(t as f64), 0.1 / 3.0, 7e-9]).collect();
    mc.records[1].step_uncertainty = vec![0.25, 1.0 / 7.0, 0.0, -0.0, 3e10, 5e-324];
    mc.records[2].reward = Some(-123.456_789_012_345_67);
    mc.records[3].step_scores[4] = f64::INFINITY;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rollouts.csv");
    nerfsv_validation::write_csv_file(&path, &mc.records).unwrap();
    let mut want = Vec::new();
    write_csv(&mut want, &mc.records).unwrap();
    assert_eq!(std::fs::read(&path).unwrap(), want);
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1, "temporary file left behind");
    // Floats read back are the floats written.
    let row: Vec<String> =
        String::from_utf8(want).unwrap().lines().nth(1).unwrap().split(',').map(String::from).collect();
    assert_eq!(row[5].parse::<f64>().unwrap(), mc.records[0].disturbances.row(0)[0]);
    assert_eq!(nerfsv_validation::read_csv_file(&path).unwrap(), mc.records);
}

#[test]
fn a_csv_that_nerfsv_did_not_write_is_refused_naming_the_line() {
    let toy = LinearToy::new(2.0);
    let mc = monte_carlo(&toy, &toy.prior(), &MonteCarloConfig { rollouts: 2 }, 1, &()).unwrap();
    let mut good = Vec::new();
    write_csv(&mut good, &mc.records).unwrap();
    let good = String::from_utf8(good).unwrap();
    let lines: Vec<&str> = good.lines().collect();
    let edit = |line: usize, f: &dyn Fn(&str) -> String| -> String {
        lines.iter().enumerate().map(|(i, l)| if i + 1 == line { f(l) } else { l.to_string() } + "\n").collect()
    };
    // Sets the field `from_end` places from the end of a line (1: the last).
    let set = |from_end: usize, value: &'static str| {
        move |l: &str| {
            let mut fields: Vec<&str> = l.split(',').collect();
            let at = fields.len() - from_end;
            fields[at] = value;
            fields.join(",")
        }
    };
    let cases: Vec<(String, usize, &str)> = vec![
        (edit(1, &|l| l.replace("log_q", "logq")), 1, "header"),
        (edit(3, &|l| l.replacen(",0,", ",x,", 1)), 3, "not a count"),
        (edit(4, &|l| l.rsplit_once(',').unwrap().0.to_string()), 4, "fields"),
        (edit(5, &set(3, "2")), 5, "lost"),
        (edit(6, &set(4, "2")), 6, "collided"),
        (edit(2, &set(2, "0")), 2, "counted"),
        (edit(3, &set(1, "0.5")), 3, "defensive_fraction"),
        (edit(4, &|l| l.replacen("mc,", "is,", 1)), 4, "unknown sampler label \"is\""),
        (lines[..1].iter().chain(&lines[2..]).map(|l| format!("{l}\n")).collect(), 2, "continue"),
    ];
    for (text, line, what) in cases {
        let e = nerfsv_validation::parse_csv(&text).unwrap_err();
        assert_eq!(e.0, line, "{what}: {e:?}");
        assert!(e.1.contains(what), "{what}: {e:?}");
    }
}
