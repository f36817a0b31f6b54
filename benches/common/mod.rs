//! The trained run the drone benchmarks fly in: `NERFSV_BENCH_RUN` (default `runs/stonehenge`,
//! made by `cargo run --release -- run`).

use std::path::PathBuf;

use nerfsv_scene::{Intrinsics, RenderSettings, Scene};
use nerfsv_sim::{Flight, SimConfig, Simulator, World, WorldKind};
use nerfsv_study::flight::{world, FlightInputs};

/// The run's model and fields, the default flight planned on them.
pub struct BenchRun {
    pub inputs: FlightInputs,
    pub scene: Scene,
    pub cfg: SimConfig,
    pub flight: Flight,
}

impl BenchRun {
    /// The run, or `None` (with a line saying `bench` is skipped) when there is none.
    pub fn load(bench: &str) -> Option<Self> {
        let run = std::env::var_os("NERFSV_BENCH_RUN").map_or_else(|| PathBuf::from("runs/stonehenge"), PathBuf::from);
        let Ok(inputs) = nerfsv_pipeline::flight::flight_inputs(&run, true) else {
            eprintln!("{bench}: no trained run at {} (set NERFSV_BENCH_RUN); skipped", run.display());
            return None;
        };
        let scene = Scene::builtin("stonehenge").expect("built-in scene");
        let cfg = SimConfig::default();
        let flight = inputs.plan(&cfg).expect("plan");
        Some(Self { inputs, scene, cfg, flight })
    }

    /// The simulator with the dataset's 100×100 camera.
    pub fn simulator(&self) -> Simulator<'_> {
        self.flight.simulator(&self.cfg, &self.inputs.nerf, Intrinsics::from_fov_x(100, 100, 0.8))
    }

    pub fn world(&self, kind: WorldKind) -> Box<dyn World + '_> {
        world(kind, &self.inputs, Some(&self.scene), RenderSettings::default()).expect("the run has a ground truth")
    }
}
