"""Mission families (generator.flight_software.families): every family is flown and lands at home, a
survey covers its polygon, an orbit keeps to its circle, a hover holds; the mix is drawn per seed
and a dataset with it is byte-identical from the same seed; the paper profile keeps the square."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from scart_bench.generator.engine.simulate import FlightConfig, simulate
from scart_bench.generator.flight_software.families import FAMILIES, draw_mission
from scart_bench.generator.flight_software.navigator import mission_table, mission_waypoints
from scart_bench.generator.params import MissionParams
from scart_bench.generator.profiles import PROFILES, Profile

SHORT = (20.0, 40.0)  # s of planned mission: short flights, every family still its own shape


def _config(family: str, duration=SHORT, **mission) -> FlightConfig:
    m = MissionParams(ground_phase=False, families=((family, 1.0),), duration_range=duration, **mission)
    return FlightConfig(mission=m, timing="ideal")


def _truth(r, j: int) -> np.ndarray:
    steps, vals, _ = r.simulator["truth"]
    return vals[j, :np.searchsorted(steps, r.exit_step[j], side="right")]


def _seq_at_truth(r, j: int) -> np.ndarray:
    """The navigator's mission item at each truth sample of flight ``j``."""
    t_steps = r.simulator["truth"][0]
    sp_steps, sp, _ = r.simulator["setpoint"]
    k = np.searchsorted(sp_steps, t_steps, side="right") - 1
    return sp[j, np.clip(k, 0, sp.shape[1] - 1), 4][:len(_truth(r, j))]


@pytest.fixture(scope="module")
def every_family():
    """One flight of every family, all in one batch of the compiled engine."""
    seeds = [3, 4]
    out = {}
    for f in FAMILIES:
        cfg = _config(f)
        out[f] = (simulate(seeds, cfg), seeds, cfg)
    return out


@pytest.mark.parametrize("family", FAMILIES)
def test_every_family_is_flown_and_lands_at_home(every_family, family):
    r, seeds, cfg = every_family[family]
    for j, seed in enumerate(seeds):
        assert draw_mission(seed, cfg.mission).family == family
        assert r.status[j] == "landed", (family, seed)
        end = _truth(r, j)[-1]
        assert np.hypot(end[0], end[1]) < 1.5, (family, seed, end[:3])
        assert end[2] > -0.2  # on the ground
        # it flew the mission: its highest point is the drawn altitude's neighbourhood
        assert -_truth(r, j)[:, 2].min() > 0.8 * -draw_mission(seed, cfg.mission).items[:, 2].min()


def test_the_reference_engine_flies_a_hand_flown_flight_home():
    """The numpy reference step flies fly-through items as the kernel does."""
    cfg = _config("hand_flown", duration=(4.0, 5.0), takeoff_hold_s=1.0)  # seed 134: 3.7 m up, 6 stick samples
    ref = simulate([134], cfg, engine="numpy")
    ker = simulate([134], cfg, engine="kernel")
    assert ref.status == ker.status == ["landed"]
    a, b = _truth(ref, 0), _truth(ker, 0)
    assert np.hypot(*a[-1, :2]) < 1.5
    assert abs(len(a) - len(b)) <= 25  # within half a second of the kernel's landing
    k = min(len(a), len(b))
    assert np.abs(a[:k, :3] - b[:k, :3]).max() < 0.5


def test_a_survey_covers_its_polygon(every_family):
    r, seeds, cfg = every_family["survey"]
    for j, seed in enumerate(seeds):
        d = draw_mission(seed, cfg.mission)
        poly, spacing = d.shape["polygon"], d.shape["spacing"]
        track = _truth(r, j)[:, :2]
        # points spread over the polygon (bilinear in its four corners)
        s, t = np.meshgrid(np.linspace(0, 1, 15), np.linspace(0, 1, 15))
        s, t = s.ravel()[:, None], t.ravel()[:, None]
        pts = (1 - s) * (1 - t) * poly[0] + s * (1 - t) * poly[1] + s * t * poly[2] + (1 - s) * t * poly[3]
        gap = np.min(np.linalg.norm(pts[:, None, :] - track[None, ::5, :], axis=2), axis=1)
        assert gap.max() < spacing / 2 + 2.0, (seed, gap.max(), spacing)


def test_an_orbit_stays_within_2_m_of_its_circle_outside_the_entry(every_family):
    r, seeds, cfg = every_family["orbit"]
    for j, seed in enumerate(seeds):
        d = draw_mission(seed, cfg.mission)
        seq = _seq_at_truth(r, j)
        # items: take-off, entry, the circle's points (15 degrees apart), home; the entry: its first 60 degrees
        on = (seq >= 2 + 4) & (seq <= len(d.items) - 2)
        xy = _truth(r, j)[on, :2]
        assert len(xy) > 100
        off = np.abs(np.linalg.norm(xy - d.shape["centre"], axis=1) - d.shape["radius"])
        assert off.max() < 2.0, (seed, off.max())


def test_a_hover_holds_its_position(every_family):
    r, seeds, cfg = every_family["hover"]
    for j, seed in enumerate(seeds):
        d = draw_mission(seed, cfg.mission)
        seq = _seq_at_truth(r, j)
        truth = _truth(r, j)
        spot = d.items[1, :2]
        at = (seq == 1) & (np.linalg.norm(truth[:, :2] - spot, axis=1) < 0.8)
        first = np.flatnonzero(at)[0]
        held = truth[first:][seq[first:] == 1]
        assert len(held) / 50.0 > d.items[1, 4] - 1.0  # the hold lasted its time (truth at 50 Hz)
        assert np.linalg.norm(held[:, :2] - spot, axis=1).max() < 1.5
        assert np.abs(held[:, 2] - d.items[1, 2]).max() < 1.0


def test_draws_come_from_the_seed_alone_and_follow_the_mix():
    m = PROFILES["quick"].flight_config().mission
    a = draw_mission(1234, m)
    b = draw_mission(1234, dataclasses.replace(m, altitude=99.0 if a.family != "square" else m.altitude))
    np.testing.assert_array_equal(a.items, b.items)
    fams = [draw_mission(s, m).family for s in range(400)]
    share = {f: fams.count(f) / len(fams) for f in FAMILIES}
    for f, w in m.families:
        assert abs(share[f] - w) < 0.07, (f, share[f], w)
    # the batch does not change a flight's mission: its rows lead its padded table
    table = mission_table(m, [1234, 7], [np.random.default_rng(0)] * 2)[2]
    np.testing.assert_array_equal(table[0, :len(a.items)], a.items)


def test_validation_and_held_out_flights_fly_the_same_mix():
    """The conformal threshold's false-alarm rate assumes the held-out flights are drawn as the validation
    flights are: a flight's family and planned duration come from its seed, never from its place in the
    split (over 20 dataset seeds of the standard profile, the splits' mean planned duration and their
    survey and delivery shares, the two families flagged most, agree within sampling error)."""
    from scart_bench.generator.plan import normal_seeds, splits

    profile = PROFILES["standard"]
    m = profile.flight_config().mission
    split = np.array(splits(profile.n_normal, profile.n_train, profile.n_validation, profile.n_csv_source))
    diffs, long_share = [], {"validation": [], "test": []}
    for dataset_seed in range(20):
        draws = [draw_mission(s, m) for s in normal_seeds(dataset_seed, profile.n_normal)]
        planned = np.array([d.summary()["planned_duration_s"] for d in draws])
        diffs.append(planned[split == "test"].mean() - planned[split == "validation"].mean())
        for name in long_share:
            fams = [d.family for d, sp in zip(draws, split) if sp == name]
            long_share[name].append(sum(f in ("survey", "delivery") for f in fams) / len(fams))
    diffs = np.array(diffs)
    # one dataset's difference spreads by ~8 s; the mean of 20 by ~2 s
    assert abs(diffs.mean()) < 3 * diffs.std(ddof=1) / np.sqrt(len(diffs)) + 1.0, diffs
    gap = np.mean(long_share["test"]) - np.mean(long_share["validation"])
    assert abs(gap) < 0.04, (np.mean(long_share["test"]), np.mean(long_share["validation"]))


def test_a_bad_mix_is_a_clear_error():
    with pytest.raises(ValueError, match="mission family 'sqare'"):
        Profile("x", 1, 1, 1, None, missions={"sqare": 1.0}).flight_config()
    with pytest.raises(ValueError, match="airframe 'f450'"):
        Profile("x", 1, 1, 1, None, airframes={"f450": 1.0}).flight_config()
    with pytest.raises(ValueError, match="weight -1"):
        Profile("x", 1, 1, 1, None, missions={"survey": -1}).flight_config()


def _hashes(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def test_the_same_seed_gives_byte_identical_datasets_with_the_mix(tmp_path):
    from scart_bench.generator.generate import generate_dataset

    short = dataclasses.replace(PROFILES["quick"].flight_config(), timing="ideal")
    short = dataclasses.replace(short, mission=dataclasses.replace(short.mission, duration_range=(10.0, 20.0),
                                                                   ground_phase=False))
    a = generate_dataset("quick", tmp_path / "a", seed=5, n_normal=4, with_attacks=False, config=short)
    b = generate_dataset("quick", tmp_path / "b", seed=5, n_normal=4, with_attacks=False, config=short)
    ha, hb = _hashes(Path(a)), _hashes(Path(b))
    assert ha == hb and len(ha) > 8
    # each flight records what it flew
    configs = [json.loads(p.read_text()) for p in sorted(Path(a).glob("flights/*/raw/config.json"))]
    assert len(configs) == 4
    for c in configs:
        assert {"family", "airframe", "altitude_m", "cruise_speed_ms", "planned_duration_s", "wind_ms",
                "gust_sigma_ms", "mass_kg", "battery_start"} <= set(c["flight"])
        assert len(c["waypoints_ned"]) == c["flight"]["items"]  # its own mission, not padded to its batch's
        assert abs(c["flight"]["wind_ms"] - np.hypot(*c["wind_mean_ned"][:2])) < 1e-3  # the wind it flew in


def test_the_paper_profile_keeps_the_square():
    """No mix: every flight flies the jittered square as before, and dataset.json says nothing new."""
    from scart_bench.generator.plan import plan_generation

    cfg = PROFILES["paper"].flight_config()
    assert not cfg.mission.families and not cfg.airframes
    rngs = [np.random.default_rng(1), np.random.default_rng(2)]
    rngs2 = [np.random.default_rng(1), np.random.default_rng(2)]
    wps, _, table, _ = mission_table(cfg.mission, [1, 2], rngs)
    square, _ = mission_waypoints(cfg.mission, rngs2)
    np.testing.assert_array_equal(wps, square)
    assert not table[:, :, 5].any()
    plan = plan_generation("paper", n_normal=3, with_attacks=False)
    assert "families" not in plan.config_dict["flight_config"]["mission"]
    assert "airframes" not in plan.config_dict["flight_config"]
    assert "families" in plan_generation("quick", n_normal=3, with_attacks=False).config_dict["flight_config"]["mission"]


def test_the_square_profile_file_is_the_standard_profile_on_the_square():
    """examples/profiles/standard-square.toml (docs/realism.md, "Mission diversity"): the standard profile's
    counts and grid, every flight the square on the 3DR Iris, as the paper profile flies it."""
    from scart_bench.generator.like.profile_file import read_profile

    path = Path(__file__).resolve().parents[1] / "examples" / "profiles" / "standard-square.toml"
    got = read_profile(str(path))
    std = PROFILES["standard"]
    assert (got.profile.n_train, got.profile.n_validation, got.profile.n_test, got.profile.scenario_grid) == (
        std.n_train, std.n_validation, std.n_test, std.scenario_grid)
    assert not got.config.mission.families and not got.config.airframes and std.flight_config().mission.families
    assert got.config.mission == PROFILES["paper"].flight_config().mission


def test_attacked_simulation_flights_fly_the_mix_and_record_it(tmp_path):
    """An attacked flight is flown with its own airframe and mission (per airframe group) and says so."""
    from scart_bench.generator.engine.flight_batch import flight_summaries
    from scart_bench.generator.generate import generate_dataset

    cfg = dataclasses.replace(PROFILES["quick"].flight_config(), timing="ideal")
    cfg = dataclasses.replace(cfg, mission=dataclasses.replace(cfg.mission, duration_range=(10.0, 20.0),
                                                               ground_phase=False))
    out = generate_dataset("quick", tmp_path / "ds", seed=2, n_normal=3, config=cfg,
                           scenarios=Path(__file__).resolve().parents[1] / "data/scenarios/gps_spoof.toml")
    sims = [json.loads(p.read_text()) for p in Path(out).glob("flights/sim-*/raw/config.json")]
    assert sims and all(c["status"] in ("landed", "crashed", "timeout") for c in sims)
    for c in sims:
        assert c["flight"] == flight_summaries([c["seed"]], cfg)[0]
        assert len(c["waypoints_ned"]) >= c["flight"]["items"]
