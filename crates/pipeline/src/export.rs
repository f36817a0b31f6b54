//! `nerfsv export`: a run folder's worlds, route and failures as one 3-D scene
//! ([`nerfsv_plot::glb`], binary glTF 2.0) for Blender or any glTF viewer.
//!
//! What [`failures_scene`] reads from the run folder and what each becomes (node names as a
//! viewer's outliner shows them):
//! - `collision/gt_mesh.ply` → "GT mesh" (grey) and `nerf_collision/nerf_mesh.ply` → "NeRF mesh"
//!   (translucent green), the marching-cubes surfaces of the two collision fields, under
//!   "meshes";
//! - the flight stage's planned waypoints (`flight/stage.json`) → "route" (blue polyline);
//! - each sampler's most likely failure (`stress/stage.json` names it), flown in NeRF-sim and in
//!   GT-sim (`stress/most_likely_failure_{sampler}_{world}.csv`, every substep) → its true
//!   track (red) and the estimator's track (orange), e.g. "cem NeRF-sim rollout 1/3 most likely
//!   failure true", under "most likely failures";
//! - the other failing rollouts of the searches (`stress/rollouts.csv`) and of their replays
//!   (`stress/replay_gt.csv`) → their true tracks (red; the position at the end of each step up
//!   to the crash), e.g. "cem-is NeRF-sim rollout 0/17 true", under "failing rollouts, NeRF-sim"
//!   and "failing rollouts, GT-sim". The run keeps no estimated positions of these rollouts
//!   (their journal keeps only the size of the estimator's error), so they have no estimate
//!   track. At most [`ExportOptions::max_tracks`] of them are taken, in turn from each sampler
//!   and world (NeRF-sim's first), each group in the order its file lists them.
//!
//! A piece whose stage did not run (a world without a ground truth has no GT mesh) is left out
//! and said so in [`ExportFigures::notes`]. Coordinates are nerfsv's (metres, z up) turned to
//! glTF's y up by the writer: `(x, y, z)` → `(x, z, −y)`.

use std::path::{Path, PathBuf};

use nerfsv_plot::glb::{GlbMaterial, GlbNode, GlbScene, GlbShape};
use nerfsv_scene::mesh::{load_mesh, LoadError, MeshError, MeshOptions};
use nerfsv_sim::WorldKind;
use nerfsv_study::stress::{most_likely_failure_stem, replay_csv, Sampler, ROLLOUTS_CSV};
use nerfsv_validation::{Label, RolloutRecord};
use serde::{Deserialize, Serialize};

use crate::collision::CollisionStage;
use crate::flight::FlightStage;
use crate::layout::{summary_path, RECORD};
use crate::nerf_collision::NerfCollisionStage;
use crate::stage::Stage;
use crate::stress::StressStage;
use crate::PipelineError;

/// How much [`failures_scene`] takes.
#[derive(Clone, Copy, Debug)]
pub struct ExportOptions {
    /// Most failing rollouts exported besides the most likely failures.
    pub max_tracks: usize,
}

impl Default for ExportOptions {
    fn default() -> Self {
        Self { max_tracks: 50 }
    }
}

/// What an export holds.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ExportFigures {
    /// The meshes exported ("GT mesh", "NeRF mesh") with their triangle counts.
    pub meshes: Vec<(String, usize)>,
    /// Points of the planned route (0: no flight stage).
    pub route_points: usize,
    /// Most likely failures' flights exported (one per sampler and world), each a true and an
    /// estimated track.
    pub most_likely_failure_flights: usize,
    /// Failing rollouts in the run (searches and replays, the most likely failures' own records
    /// left out) and how many of them were exported.
    pub failing_rollouts: usize,
    pub failing_rollouts_exported: usize,
    /// Polylines in the file besides the route (tracks).
    pub tracks: usize,
    /// glTF nodes in the file (one per mesh or polyline, one per group).
    pub nodes: usize,
    /// What was left out and why.
    pub notes: Vec<String>,
}

// Materials, by index into the scene's.
const GT_MESH: usize = 0;
const NERF_MESH: usize = 1;
const ROUTE: usize = 2;
const TRUE_TRACK: usize = 3;
const ESTIMATE: usize = 4;

fn materials() -> Vec<GlbMaterial> {
    let m = |name: &str, rgba: [f32; 4]| GlbMaterial { name: name.into(), rgba };
    vec![
        m("GT mesh (grey)", [0.55, 0.55, 0.55, 1.0]),
        m("NeRF mesh (translucent green)", [0.1, 0.75, 0.2, 0.35]),
        m("route (blue)", [0.05, 0.25, 0.9, 1.0]),
        m("true track (red)", [0.9, 0.05, 0.05, 1.0]),
        m("estimated track (orange)", [1.0, 0.45, 0.0, 1.0]),
    ]
}

/// How a world is named in node names.
fn world_name(world: WorldKind) -> &'static str {
    match world {
        WorldKind::Nerf => "NeRF-sim",
        WorldKind::Gt => "GT-sim",
    }
}

fn bad_file(path: &Path, message: impl std::fmt::Display) -> PipelineError {
    PipelineError::RunFile { path: path.to_path_buf(), message: message.to_string() }
}

/// A stage record's figures (`RUN/STAGE/stage.json`), `None` when the stage has no record.
fn read_figures<T: for<'de> Deserialize<'de>>(root: &Path, stage: &str) -> Result<Option<T>, PipelineError> {
    #[derive(Deserialize)]
    struct Record<T> {
        figures: T,
    }
    let path = root.join(stage).join(RECORD);
    let text = match std::fs::read_to_string(&path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        r => r.map_err(|e| PipelineError::io(&path, e))?,
    };
    let record: Record<T> = serde_json::from_str(&text).map_err(|e| bad_file(&path, e))?;
    Ok(Some(record.figures))
}

/// What the export reads of the flight stage's figures.
#[derive(Deserialize)]
struct FlightRoute {
    waypoints: Vec<[f64; 3]>,
}

/// What the export reads of the stress stage's figures.
#[derive(Deserialize)]
struct StressSummary {
    world: WorldKind,
    replay_world: Option<WorldKind>,
    samplers: Vec<SamplerSummary>,
}

#[derive(Deserialize)]
struct SamplerSummary {
    sampler: Sampler,
    most_likely_failure: Option<FailureId>,
}

#[derive(Deserialize, Clone, Copy)]
struct FailureId {
    sampler: Label,
    population: usize,
    index: usize,
    /// Whether the same disturbances crashed in the replay's world (absent: not replayed).
    #[serde(default)]
    replay_collided: Option<bool>,
}

impl FailureId {
    fn is(&self, r: &RolloutRecord) -> bool {
        (self.sampler, self.population, self.index) == (r.sampler, r.population, r.index)
    }
}

fn point(p: [f64; 3]) -> [f32; 3] {
    p.map(|v| v as f32)
}

/// A surface mesh as a node, or a note when its stage did not write it (or it is empty).
fn mesh_node(
    path: &Path,
    name: &str,
    material: usize,
    f: &mut ExportFigures,
) -> Result<Option<GlbNode>, PipelineError> {
    if !path.is_file() {
        f.notes.push(format!("no {name}: {} is absent", path.display()));
        return Ok(None);
    }
    let mesh = match load_mesh(path, MeshOptions::default()) {
        Err(LoadError::Invalid { error: MeshError::NoTriangles, .. }) => {
            f.notes.push(format!("no {name}: {} has no triangles", path.display()));
            return Ok(None);
        }
        r => r.map_err(PipelineError::Mesh)?.mesh,
    };
    f.meshes.push((name.to_owned(), mesh.triangles.len()));
    let positions = mesh.positions.iter().map(|p| [p.x, p.y, p.z]).collect();
    Ok(Some(GlbNode {
        name: name.to_owned(),
        group: Some("meshes".into()),
        material,
        shape: GlbShape::Triangles { positions, triangles: mesh.triangles },
    }))
}

/// A polyline's points (nerfsv's frame, metres).
type Points = Vec<[f32; 3]>;

/// The true and estimated positions of every substep of a flight CSV
/// ([`nerfsv_sim::read_trajectory`]).
fn read_flight_csv(path: &Path) -> Result<(Points, Points), PipelineError> {
    let rows = nerfsv_sim::read_trajectory(path)?;
    let point = |p: &nerfsv_sim::TrajectoryPose| -> [f32; 3] { p.position.map(|v| v as f32).into() };
    Ok(rows.iter().map(|r| (point(&r.truth), point(&r.estimate))).unzip())
}

/// A track's node, or `None` when fewer than two of its points are finite.
fn track(name: String, group: &str, material: usize, points: Vec<[f32; 3]>) -> Option<GlbNode> {
    let points: Vec<[f32; 3]> = points.into_iter().filter(|p| p.iter().all(|v| v.is_finite())).collect();
    (points.len() >= 2).then(|| GlbNode {
        name,
        group: Some(group.into()),
        material,
        shape: GlbShape::LineStrip { points },
    })
}

/// The most likely failures' flights in each world: a true and an estimated track each.
fn most_likely_failures(
    dir: &Path,
    stress: &StressSummary,
    scene: &mut GlbScene,
    f: &mut ExportFigures,
) -> Result<(), PipelineError> {
    let worlds = std::iter::once(stress.world).chain(stress.replay_world);
    let worlds: Vec<WorldKind> = worlds.collect();
    for s in &stress.samplers {
        let Some(id) = s.most_likely_failure else { continue };
        for &world in &worlds {
            let path = dir.join(format!("{}_{}.csv", most_likely_failure_stem(s.sampler), world.name()));
            if !path.is_file() {
                f.notes.push(format!("{} is absent", path.display()));
                continue;
            }
            let (truth, estimate) = read_flight_csv(&path)?;
            // Found in the search's world; flown again in the replay's, where it may not crash.
            let crashed = world == stress.world || id.replay_collided != Some(false);
            let name = |what: &str| {
                format!(
                    "{} {} rollout {}/{} most likely failure{} {what}",
                    id.sampler,
                    world_name(world),
                    id.population,
                    id.index,
                    if crashed { "" } else { " (no crash here)" }
                )
            };
            let group = "most likely failures";
            let nodes =
                [track(name("true"), group, TRUE_TRACK, truth), track(name("estimate"), group, ESTIMATE, estimate)];
            if nodes.iter().any(Option::is_none) {
                f.notes.push(format!("{}: fewer than two finite positions; left out", path.display()));
                continue;
            }
            scene.nodes.extend(nodes.into_iter().flatten());
            f.most_likely_failure_flights += 1;
        }
    }
    Ok(())
}

/// The failing rollouts of `records` (flown in `world`) grouped by sampler label, the most likely
/// failures' own records left out.
fn failing_by_sampler(
    records: Vec<RolloutRecord>,
    world: WorldKind,
    mlf: &[FailureId],
) -> Vec<(WorldKind, Vec<RolloutRecord>)> {
    let mut groups: Vec<(Label, Vec<RolloutRecord>)> = Vec::new();
    for r in records.into_iter().filter(|r| r.failed && !mlf.iter().any(|id| id.is(r))) {
        match groups.iter_mut().find(|(l, _)| *l == r.sampler) {
            Some((_, g)) => g.push(r),
            None => groups.push((r.sampler, vec![r])),
        }
    }
    groups.into_iter().map(|(_, g)| (world, g)).collect()
}

/// Up to `max` failing rollouts' true tracks, taken in turn from each (world, sampler) group.
fn failing_rollouts(
    dir: &Path,
    stress: &StressSummary,
    max: usize,
    scene: &mut GlbScene,
    f: &mut ExportFigures,
) -> Result<(), PipelineError> {
    let mlf: Vec<FailureId> = stress.samplers.iter().filter_map(|s| s.most_likely_failure).collect();
    let mut files = vec![(dir.join(ROLLOUTS_CSV), stress.world)];
    files.extend(stress.replay_world.map(|w| (dir.join(replay_csv(w)), w)));
    let mut groups = Vec::new();
    for (path, world) in files {
        if !path.is_file() {
            f.notes.push(format!("{} is absent", path.display()));
            continue;
        }
        groups.extend(failing_by_sampler(nerfsv_validation::read_csv_file(&path)?, world, &mlf));
    }
    f.failing_rollouts = groups.iter().map(|(_, g)| g.len()).sum();
    let mut queues: Vec<_> = groups.into_iter().map(|(w, g)| (w, g.into_iter())).collect();
    let (mut short, mut more) = (0, true);
    while more && f.failing_rollouts_exported < max {
        more = false;
        for (world, queue) in &mut queues {
            if f.failing_rollouts_exported >= max {
                break;
            }
            let Some(r) = queue.next() else { continue };
            more = true;
            let name = format!("{} {} rollout {}/{} true", r.sampler, world_name(*world), r.population, r.index);
            let points = r.step_positions.iter().take(r.counted_steps()).map(|&p| point(p)).collect();
            match track(name, &format!("failing rollouts, {}", world_name(*world)), TRUE_TRACK, points) {
                Some(node) => {
                    scene.nodes.push(node);
                    f.failing_rollouts_exported += 1;
                }
                None => short += 1,
            }
        }
    }
    if short > 0 {
        f.notes.push(format!("{short} failing rollouts have fewer than two finite positions; left out"));
    }
    if f.failing_rollouts_exported < f.failing_rollouts {
        f.notes.push(format!(
            "{} of {} failing rollouts exported (--max-tracks {max})",
            f.failing_rollouts_exported, f.failing_rollouts
        ));
    }
    Ok(())
}

/// The run folder `root`'s meshes, route and failures as a scene (see the module docs), with
/// what it holds. Refuses a folder without a `summary.json`.
pub fn failures_scene(root: &Path, options: ExportOptions) -> Result<(GlbScene, ExportFigures), PipelineError> {
    if !summary_path(root).is_file() {
        return Err(PipelineError::NotARun { path: root.to_path_buf() });
    }
    let mut f = ExportFigures::default();
    let mut scene = GlbScene { materials: materials(), nodes: Vec::new() };
    let gt = root.join(CollisionStage::NAME).join(CollisionStage::MESH);
    let nerf = root.join(NerfCollisionStage::NAME).join(NerfCollisionStage::MESH);
    scene.nodes.extend(mesh_node(&gt, "GT mesh", GT_MESH, &mut f)?);
    scene.nodes.extend(mesh_node(&nerf, "NeRF mesh", NERF_MESH, &mut f)?);
    match read_figures::<FlightRoute>(root, FlightStage::NAME)? {
        Some(route) if route.waypoints.len() >= 2 => {
            f.route_points = route.waypoints.len();
            let points = route.waypoints.into_iter().map(point).collect();
            scene.nodes.extend(track("route (planned waypoints)".into(), "route", ROUTE, points));
        }
        _ => f.notes.push(format!("no route: {} has no planned waypoints", route_record(root).display())),
    }
    match read_figures::<StressSummary>(root, StressStage::NAME)? {
        Some(stress) => {
            let dir = root.join(StressStage::NAME);
            most_likely_failures(&dir, &stress, &mut scene, &mut f)?;
            failing_rollouts(&dir, &stress, options.max_tracks, &mut scene, &mut f)?;
        }
        None => f.notes.push(format!(
            "no failures: {} is absent (the stress stage has not run)",
            root.join(StressStage::NAME).join(RECORD).display()
        )),
    }
    f.tracks = scene.nodes.iter().filter(|n| n.material == TRUE_TRACK || n.material == ESTIMATE).count();
    let mut groups: Vec<&str> = scene.nodes.iter().filter_map(|n| n.group.as_deref()).collect();
    groups.sort_unstable();
    groups.dedup();
    f.nodes = scene.nodes.len() + groups.len();
    Ok((scene, f))
}

fn route_record(root: &Path) -> PathBuf {
    root.join(FlightStage::NAME).join(RECORD)
}
