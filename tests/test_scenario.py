"""Scenario schema: profiles evaluated at hand-computed points, validation names file and field."""

from __future__ import annotations

import numpy as np
import pytest

from models.scenario import Event, Periodic, Profile, Scenario
from service.sim.scenarios import ScenarioError, load_scenario


def test_paper_bench_sequence_matches_physics_md_section_5():
    s = load_scenario("paper_bench")
    assert s.duration_s == 1.0 and s.step_s == 1e-4 and s.n_steps() == 10_000
    u = s.inputs(np.array([0.0, 0.2999, 0.30, 0.3499, 0.35, 0.7499, 0.75, 1.0]))
    np.testing.assert_allclose(u["x_cmd"], 0.02)
    np.testing.assert_allclose(u["f_r"], [0, 0, 12e3, 12e3, 12e3, 12e3, -12e3, -12e3])
    np.testing.assert_allclose(u["p_sr"], [20e6] * 4 + [10e6] * 4)
    np.testing.assert_allclose(u["c_lk"], 2e-13)


def test_breakpoints_fall_on_step_boundaries_of_paper_bench():
    s = load_scenario("paper_bench")
    for prof in (s.command, s.load, s.supply):
        for tb in prof.breakpoints():
            k = tb / s.step_s
            assert abs(k - round(k)) < 1e-9


def test_ramp_and_step_profile_values():
    # ramp from 2e-13 at t=1 to 2e-12 at t=3 (halfway at t=2: 1.1e-12), then a step to 0 at t=5
    prof = Profile(
        initial=2e-13,
        events=[Event(t=1.0, value=2e-12, ramp_s=2.0), Event(t=5.0, value=0.0)],
    )
    y = prof.sample([0.0, 1.0, 2.0, 3.0, 4.9, 5.0])
    np.testing.assert_allclose(y, [2e-13, 2e-13, 1.1e-12, 2e-12, 2e-12, 0.0], rtol=1e-12)


def test_periodic_components():
    prof = Profile(
        initial=1.0,
        periodic=[Periodic(kind="sine", amplitude=2.0, freq_hz=1.0, t_start=1.0, t_end=3.0)],
    )
    # sin(2 pi 0.25) = 1 at t = 1.25; off before t_start and after t_end
    np.testing.assert_allclose(
        prof.sample([0.5, 1.25, 1.75, 3.5]), [1.0, 3.0, -1.0, 1.0], atol=1e-12
    )
    sq = Profile(periodic=[Periodic(kind="square", amplitude=0.5, freq_hz=2.0)])
    np.testing.assert_allclose(sq.sample([0.1, 0.3]), [0.5, -0.5])


def test_unsorted_events_rejected():
    with pytest.raises(ValueError, match="sorted"):
        Profile(events=[Event(t=2.0, value=1.0), Event(t=1.0, value=0.0)])


def test_param_overrides_validated():
    s = Scenario(name="x", duration_s=0.1, params={"c_lk": 4e-13, "mass": 50.0})
    p = s.eha_params()
    assert p.c_lk == 4e-13 and p.mass == 50.0
    with pytest.raises(ValueError, match="unknown parameter"):
        Scenario(name="x", duration_s=0.1, params={"c_leak": 1.0})
    with pytest.raises(ValueError, match="mass"):
        Scenario(name="x", duration_s=0.1, params={"mass": -1.0})


def test_invalid_file_error_names_file_and_field(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "bad"\nduration_s = -1.0\n[load]\ninitial = "heavy"\n')
    with pytest.raises(ScenarioError) as ei:
        load_scenario(bad)
    msg = str(ei.value)
    assert str(bad) in msg
    assert "duration_s" in msg and "load.initial" in msg


def test_unreadable_toml_and_missing_file(tmp_path):
    bad = tmp_path / "broken.toml"
    bad.write_text("duration_s = = 1\n")
    with pytest.raises(ScenarioError, match="broken.toml"):
        load_scenario(bad)
    with pytest.raises(ScenarioError, match="no such scenario"):
        load_scenario(tmp_path / "nope.toml")


def test_every_bundled_scenario_validates():
    from service.sim.scenarios import SCENARIO_DIR

    files = sorted(SCENARIO_DIR.glob("*.toml"))
    assert files
    for f in files:
        s = load_scenario(f)
        assert s.n_steps() > 0
