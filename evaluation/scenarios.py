"""The bundled scenarios the benchmark and the noise-seed comparison run the monitor on."""

from __future__ import annotations

from service.sim.scenarios import load_scenario

SCENARIOS = ("healthy_noise", "leak_ramp", "leak_step", "supply_drop", "combined")
# outside the C-types' domain (docs/models.md section 4; full channel set only)
SCENARIOS_WH = ("est_overload", "est_large_steps", "est_load_reversal")


def bundled_scenario(name: str, duration: float | None = None, leak: float | None = None):
    """Bundled scenario ``name``, optionally ``duration`` [s] long, or with a leak step to
    ``leak`` [m^3/s/Pa] at 1.5 s (e.g. 2x nominal = an increase of 1x) in place of its own."""
    from models.scenario import Event, Profile

    sc = load_scenario(name)
    if duration is not None:
        sc = sc.model_copy(update={"duration_s": duration, "name": f"{name}_{duration:g}s"})
    if leak is not None:
        prof = Profile(initial=2e-13, events=[Event(t=1.5, value=leak)])
        sc = sc.model_copy(update={"leak": prof, "name": f"{name}_{leak / 2e-13:g}x"})
    return sc
