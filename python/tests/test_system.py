"""Your own system under test from Python, and the drone's stress test with the command line's
options.

The toy: 10 steps of a 1-dimensional N(0, 1) disturbance, failing when any step's exceeds a
threshold (one-sided), so P(fail) = 1 − Φ(threshold)^10 in closed form: ≈ 0.2056 at 2σ for
Monte Carlo, CEM and importance sampling, ≈ 0.0134 at 3σ where subset simulation needs more
than one level. The drone's tests build the small study of test_nerfsv.py with the `nerfsv`
binary (NERFSV_BIN, else the workspace's target/release/nerfsv).
"""

import json
import math
from pathlib import Path

import numpy as np
import pytest

import nerfsv

from common import cli, tiny_world


def p_fail(threshold, steps=10):
    phi = 0.5 * (1.0 + math.erf(threshold / math.sqrt(2.0)))
    return 1.0 - phi**steps


class Interrupted(Exception):
    """What the toy raises to simulate an interrupted run."""


class Toy:
    """Fails when a step's disturbance exceeds `threshold`; the miss distance is
    threshold − max x (negative for a failure: how deep). Counts its calls; raises
    `Interrupted` on the call after `fail_after`."""

    steps = 10
    dim = 1

    def __init__(self, threshold=2.0, fail_after=None):
        self.threshold, self.fail_after, self.calls = threshold, fail_after, 0

    def run(self, disturbances, seed):
        assert disturbances.shape == (10, 1) and disturbances.dtype == np.float64
        assert isinstance(seed, int)
        self.calls += 1
        if self.fail_after is not None and self.calls > self.fail_after:
            raise Interrupted(f"call {self.calls}")
        top = float(disturbances[:, 0].max())
        return top > self.threshold, self.threshold - top


class BatchToy(Toy):
    """The toy with `run_batch`: counts the batches and the rollouts in them; raises
    `Interrupted` instead of running batch number `cut` (from 0)."""

    def __init__(self, threshold=2.0, cut=None):
        super().__init__(threshold)
        self.batches, self.batched, self.cut = 0, 0, cut

    def run_batch(self, disturbances, seeds):
        if self.batches == self.cut:
            raise Interrupted(f"batch {self.cut}")
        assert disturbances.ndim == 3 and disturbances.shape[1:] == (10, 1) and seeds.shape == disturbances.shape[:1]
        self.batches += 1
        self.batched += len(seeds)
        top = disturbances[:, :, 0].max(axis=1)
        return [(bool(t > self.threshold), float(self.threshold - t)) for t in top]


MC = ["stress.monte_carlo.rollouts=2000"]
CEM = ["stress.cem.m=200", "stress.cem.m_elite=40", "stress.cem.k_max=3", "stress.cem.is_samples=2000"]


def stress(system, sampler, small=False, **kw):
    """The toy's search with the tests' settings; `small`: fewer rollouts (a journal is a file each)."""
    overrides = {"mc": MC, "cem": CEM, "subset": [], "is": ["stress.cem.is_samples=2000"]}[sampler]
    if small and sampler == "cem":
        overrides = ["stress.cem.m=50", "stress.cem.m_elite=10", "stress.cem.k_max=3",
                     "stress.cem.is_samples=200"]
    return nerfsv.stress(system=system, sampler=sampler, std=1.0, overrides=overrides, **kw)


def assert_same(a, b):
    assert a.keys() == b.keys()
    for k in a:
        if isinstance(a[k], np.ndarray):
            assert np.array_equal(a[k], b[k]), k
        elif k == "most_likely_failure" and a[k] is not None:
            assert_same(a[k], b[k])
        elif k != "out":
            assert a[k] == b[k], k


def test_monte_carlo_covers_the_closed_form_failure_probability():
    p = p_fail(2.0)
    assert abs(p - 0.2056) < 1e-4
    r = stress(Toy(), "mc", seed=1)
    assert r["sampler"] == "mc" and r["rollouts"] == 2000 and r["failures"] == int(r["failed"].sum())
    lo, hi = r["interval"]
    assert lo < p < hi, r["interval"]
    assert r["probability"] == r["failures"] / 2000
    assert r["standard_error"] == pytest.approx(math.sqrt(r["probability"] * (1 - r["probability"]) / 2000))
    # Failure ⇔ score ≤ 0; a failure scores its (negative) miss distance.
    assert np.all(r["scores"][r["failed"]] <= 0) and np.all(r["scores"][~r["failed"]] > 0)
    mlf = r["most_likely_failure"]
    assert mlf["disturbances"].shape == (10, 1) and mlf["disturbances"].max() > 2.0 and mlf["score"] <= 0
    # Over several seeds: a 95 % interval covers p in (nearly) all of them, the estimates centre on p.
    runs = [stress(Toy(), "mc", seed=s) for s in range(8)]
    covered = sum(x["interval"][0] < p < x["interval"][1] for x in runs)
    assert covered >= 7, [x["interval"] for x in runs]
    mean = np.mean([x["probability"] for x in runs])
    assert abs(mean - p) < 3 * math.sqrt(p * (1 - p) / (8 * 2000)), mean


def test_subset_simulation_covers_the_closed_form_failure_probability():
    # At 2σ failures are commoner than p0 = 0.1: one level, Monte Carlo from the prior.
    p = p_fail(2.0)
    r = stress(Toy(), "subset", seed=1)
    assert r["levels"] == 1 and r["interval"][0] < p < r["interval"][1], r
    runs = [stress(Toy(), "subset", seed=s) for s in range(6)]
    assert sum(x["interval"][0] < p < x["interval"][1] for x in runs) >= 5, [x["interval"] for x in runs]
    # At 3σ the chains must climb: more than one level, and the interval still covers.
    p3 = p_fail(3.0)
    runs = [stress(Toy(3.0), "subset", seed=s) for s in range(6)]
    assert all(x["levels"] >= 2 and len(x["thresholds"]) == x["levels"] - 1 for x in runs)
    covered = sum(x["interval"][0] < p3 < x["interval"][1] for x in runs)
    assert covered >= 5, [(x["probability"], x["interval"]) for x in runs]
    assert all(x["rollouts"] == 200 + (x["levels"] - 1) * 180 for x in runs)
    assert abs(np.mean([x["probability"] for x in runs]) / p3 - 1) < 0.5


def test_the_cross_entropy_methods_importance_estimate_is_within_a_few_standard_errors():
    p = p_fail(2.0)
    r = stress(Toy(), "cem", seed=3)
    assert r["rollouts"] == 3 * 200 + 2000 and r["is_samples"] == 2000
    assert r["labels"].count("cem") == 600 and r["labels"].count("cem-is") == 2000
    assert 0 < r["standard_error"] < 0.05 and abs(r["probability"] - p) < 4 * r["standard_error"], r
    assert r["proposal_mean"].shape == (10, 1) and r["proposal_std"].shape == (10, 1)
    # Importance sampling from the prior itself is Monte Carlo with weights 1.
    q = stress(Toy(), "is", seed=3, proposal=(0.0, 1.0))
    assert q["effective_sample_size"] == pytest.approx(2000) and abs(q["probability"] - p) < 4 * q["standard_error"]


@pytest.mark.parametrize("sampler", ["mc", "cem", "subset"])
def test_the_same_seed_gives_the_same_results_and_another_seed_others(sampler):
    t = 3.0 if sampler == "subset" else 2.0
    a, b = stress(Toy(t), sampler, seed=11), stress(Toy(t), sampler, seed=11)
    assert_same(a, b)
    c = stress(Toy(t), sampler, seed=12)
    assert not np.array_equal(a["scores"], c["scores"])


@pytest.mark.parametrize("sampler", ["cem", "subset"])
def test_a_resumed_run_equals_an_uninterrupted_one_without_running_a_recorded_rollout_again(sampler, tmp_path):
    t = 3.0 if sampler == "subset" else 2.0  # subset simulation: several levels of chains
    whole = Toy(t)
    full = stress(whole, sampler, True, seed=4, out=tmp_path / "full")
    assert (tmp_path / "full" / "rollouts.csv").is_file()
    n = 120 if sampler == "cem" else 450  # within CEM's third population; subset simulation's third level
    with pytest.raises(Interrupted, match=f"call {n + 1}"):
        stress(Toy(t, fail_after=n), sampler, True, seed=4, out=tmp_path / "cut")
    assert not (tmp_path / "cut" / "rollouts.csv").exists()
    rest = Toy(t)
    resumed = stress(rest, sampler, True, seed=4, out=tmp_path / "cut", resume=True)
    assert rest.calls == whole.calls - n, (rest.calls, whole.calls)
    assert_same(resumed, full)
    assert (tmp_path / "cut" / "rollouts.csv").read_bytes() == (tmp_path / "full" / "rollouts.csv").read_bytes()
    # Another seed's journal, or another system's, is refused, not mixed in.
    with pytest.raises(ValueError, match="another configuration"):
        stress(Toy(t), sampler, True, seed=5, out=tmp_path / "cut", resume=True)
    other = Toy(t)
    other.key = "threshold 2.5"
    with pytest.raises(ValueError, match="another configuration"):
        stress(other, sampler, True, seed=4, out=tmp_path / "cut", resume=True)


def test_a_run_batch_that_raises_is_resumed_from_the_populations_before_it(tmp_path):
    whole = BatchToy()
    full = stress(whole, "cem", True, seed=6, out=tmp_path / "full")
    with pytest.raises(Interrupted, match="batch 2"):
        stress(BatchToy(cut=2), "cem", True, seed=6, out=tmp_path / "cut")
    rest = BatchToy()
    assert_same(stress(rest, "cem", True, seed=6, out=tmp_path / "cut", resume=True), full)
    assert rest.batches == 2 and rest.batched == whole.batched - 2 * 50


@pytest.mark.parametrize("sampler", ["mc", "cem"])
def test_run_batch_is_one_call_per_population_with_the_results_of_run(sampler):
    batched = BatchToy()
    b = stress(batched, sampler, seed=2)
    assert batched.calls == 0 and batched.batched == b["rollouts"]
    assert batched.batches == (1 if sampler == "mc" else 3 + 1)
    assert_same(b, stress(Toy(), sampler, seed=2))


def test_subset_simulation_flies_level_zero_and_each_move_of_every_chain_as_one_batch():
    batched = BatchToy(3.0)
    b = stress(batched, "subset", seed=2)
    assert b["levels"] == 2 and batched.calls == 0 and batched.batched == b["rollouts"]
    # Level 0 in one batch, then level 1's 20 chains of 10 states: 9 moves, each one batch.
    assert batched.batches == 1 + 9
    assert_same(b, stress(Toy(3.0), "subset", seed=2))


def test_the_rollouts_csv_is_the_command_lines_layout(tmp_path):
    r = nerfsv.stress(system=Toy(), sampler="mc", std=1.0, seed=1, out=tmp_path,
                      overrides=["stress.monte_carlo.rollouts=50"])
    lines = (tmp_path / "rollouts.csv").read_text().splitlines()
    header = lines[0].split(",")
    assert header[:5] == ["sampler", "population", "index", "seed", "step"], header
    assert len(lines) == 1 + 50 * 10
    first = dict(zip(header, lines[1].split(",")))
    assert first["sampler"] == "mc" and int(first["seed"]) == int(r["seeds"][0])


class Returns(Toy):
    def __init__(self, value):
        super().__init__()
        self.value = value

    def run(self, disturbances, seed):
        return self.value


class BadBatch(BatchToy):
    def run_batch(self, disturbances, seeds):
        return super().run_batch(disturbances, seeds)[:-1]


def test_bad_returns_and_arguments_raise_value_error_naming_the_rollout():
    for value, message in [
        ((True, float("nan")), r"system.run\(disturbances, seed=\d+\): miss_distance must be a finite number"),
        ((False, -0.5), "a pass with a negative miss distance"),
        ((True, 1.0, 2.0), "not a pair"),
        (0.5, "not a pair"),
        (("yes", 1.0), "failed must be a bool"),
        ((True, "far"), "miss_distance must be a number"),
    ]:
        with pytest.raises(ValueError, match=message):
            nerfsv.stress(system=Returns(value), sampler="mc", std=1.0, overrides=["stress.monte_carlo.rollouts=5"])
    with pytest.raises(ValueError, match=r"returned 1 results for 2 rollouts"):
        nerfsv.stress(system=BadBatch(), sampler="mc", std=1.0, overrides=["stress.monte_carlo.rollouts=2"])
    # A failure's positive miss distance counts as 0, a pass's 0 as just above: the flag decides.
    r = nerfsv.stress(system=Returns((True, 3.0)), sampler="mc", std=1.0, overrides=["stress.monte_carlo.rollouts=3"])
    assert r["failures"] == 3 and np.all(r["scores"] == 0)
    r = nerfsv.stress(system=Returns((False, 0)), sampler="mc", std=1.0, overrides=["stress.monte_carlo.rollouts=3"])
    assert r["failures"] == 0 and np.all(r["scores"] > 0)
    with pytest.raises(ValueError, match="std: the prior has 2 components per step, the system's dim is 1"):
        nerfsv.stress(system=Toy(), std=[1.0, 1.0])
    with pytest.raises(ValueError, match="stress.disturbance: the prior has 12 components"):
        nerfsv.stress(system=Toy())
    with pytest.raises(ValueError, match="sampler: unknown sampler \"nope\""):
        nerfsv.stress(system=Toy(), sampler="nope", std=1.0)
    with pytest.raises(ValueError, match="system: has no attribute `steps`"):
        nerfsv.stress(system=object(), std=1.0)
    with pytest.raises(ValueError, match="stress.cem.m_elite"):
        nerfsv.stress(system=Toy(), sampler="cem", std=1.0, overrides=["stress.cem.m_elite=99"])
    with pytest.raises(ValueError, match="proposal"):
        nerfsv.stress(system=Toy(), sampler="is", std=1.0)
    with pytest.raises(ValueError, match="resume"):
        nerfsv.stress(system=Toy(), std=1.0, resume=True)
    with pytest.raises(ValueError, match="system: world, reward: the drone's arguments"):
        nerfsv.stress(system=Toy(), std=1.0, world="gt", reward="ga")


class RaisingBatch(BatchToy):
    def run_batch(self, disturbances, seeds):
        raise Interrupted("call 3")


@pytest.mark.parametrize("sampler,system", [("subset", Toy(fail_after=2)), ("mc", Toy(fail_after=2)),
                                            ("cem", RaisingBatch())])
def test_an_exception_in_run_propagates_as_itself(sampler, system):
    with pytest.raises(Interrupted, match="call 3") as e:
        nerfsv.stress(system=system, sampler=sampler, std=1.0)
    notes = getattr(e.value, "__notes__", None)
    call = "system.run_batch(disturbances [10, 10, 1]" if sampler == "cem" else "system.run(disturbances, seed="
    assert notes is None or any(call in n for n in notes), notes


# The drone: the small study of test_nerfsv.py.
@pytest.fixture(scope="module")
def world(tmp_path_factory):
    return tiny_world(tmp_path_factory.mktemp("world"), field=True)


def outputs(folder):
    """The stress folder's files by relative path, stress.json without its timings."""
    files = {}
    for p in sorted(Path(folder).rglob("*")):
        if p.is_file():
            b = p.read_bytes()
            if p.name == "stress.json":
                v = json.loads(b)
                for k in ["seconds", "rollouts_per_second", "uncertainty_seconds"]:
                    v.pop(k, None)
                b = json.dumps(v, sort_keys=True).encode()
            files[str(p.relative_to(folder))] = b
    return files


@pytest.mark.parametrize("flag,method,sampler", [("--reward", "ga", "cem"), ("--measure", "ga", "mc")])
def test_python_stress_with_reward_or_measure_equals_the_cli(world, tmp_path, flag, method, sampler):
    cli("stress", "--scene", "monolith", "--model", world["model"], "--nerf-field", world["field"], "--config",
        world["study"], "--sampler", sampler, flag, method, "--out", tmp_path / "cli")
    kw = {flag[2:]: method}
    figures = nerfsv.stress(world["model"], tmp_path / "py", sampler=sampler, config=world["study"], scene="monolith",
                            nerf_field=world["field"], **kw)
    assert figures["online"] == {"method": method, "mode": "exact", "reward": flag == "--reward"}
    py, ref = outputs(tmp_path / "py"), outputs(tmp_path / "cli")
    assert py.keys() == ref.keys() and py == ref
    with pytest.raises(ValueError, match="reward, measure: give one of them"):
        nerfsv.stress(world["model"], tmp_path / "x", reward="ga", measure="ga")
    with pytest.raises(ValueError, match="reward: unknown"):
        nerfsv.stress(world["model"], tmp_path / "x", reward="nope")


def test_a_model_flies_and_stresses_as_its_checkpoint_path(world, tmp_path):
    model = nerfsv.Model.load(world["model"])
    kw = dict(world="gt", estimator="truth", config=world["study"], scene="monolith", nerf_field=world["field"])
    by_path, by_model = nerfsv.fly(world["model"], random_seed=3, **kw), nerfsv.fly(model, random_seed=3, **kw)
    untimed = lambda f: {k: v for k, v in f.items() if "seconds" not in k}  # noqa: E731
    assert untimed(by_path["figures"]) == untimed(by_model["figures"])
    assert all(np.array_equal(by_path[k], by_model[k], equal_nan=True) for k in ["time", "position", "clearance"])
    kw = dict(sampler="mc", config=world["study"], scene="monolith", nerf_field=world["field"])
    nerfsv.stress(world["model"], tmp_path / "path", **kw)
    nerfsv.stress(model, tmp_path / "model", **kw)
    assert outputs(tmp_path / "model") == outputs(tmp_path / "path")
    # A checkpoint file that no longer holds the model is refused; a deleted one is saved anew.
    copy = tmp_path / "copy.safetensors"
    copy.write_bytes(Path(world["model"]).read_bytes())
    moved = nerfsv.Model.load(copy)
    copy.unlink()
    nerfsv.stress(moved, tmp_path / "moved", **kw)
    assert outputs(tmp_path / "moved")["rollouts.csv"] == outputs(tmp_path / "path")["rollouts.csv"]
    other = tmp_path / "other"
    cli("train", "--data", Path(world["model"]).parents[1] / "ds", "--out", other, "--steps", 3, "--config",
        Path(world["model"]).parents[1] / "nerf.toml")
    swapped = tmp_path / "swapped.safetensors"
    swapped.write_bytes(Path(world["model"]).read_bytes())
    stale = nerfsv.Model.load(swapped)
    swapped.write_bytes((other / "checkpoint.safetensors").read_bytes())
    with pytest.raises(ValueError, match="no longer holds the model"):
        nerfsv.fly(stale, **{k: v for k, v in kw.items() if k != "sampler"})
