"""The Foxglove layout of one unit (``servowatch layout --unit AC/ACT``;
deploy/foxglove/servowatch-layout.json is AC001/elevator_L's).

Panels (docs/dashboard.md, "Live in Foxglove"): C_Lk with its baseline and its alarm levels,
P_SR, the innovations (residuals) of the pressures and of the positions, NIS with its
two-sided 95 % chi-square band, the alarm states and the last alarm events. The topics and
fields are the MCAP log's (service.edge.foxglove_feed), so the layout opens a log and a live
daemon alike. Two user scripts derive what the messages do not carry: the baseline C_Lk
(C_Lk / leak_ratio) with the alarm levels (leak_raise, leak_clear of MonitorConfig), and the
NIS band of each row's degrees of freedom (scipy's chi2, tabulated here).
"""

from __future__ import annotations

import json

__all__ = ["build", "nis_band", "layout_json"]

LEAK_SCRIPT = "/foxglove_script/servowatch_leak"
NIS_SCRIPT = "/foxglove_script/servowatch_nis"


def _leak_script(est: str, health: str, raise_: float, clear: float) -> str:
    return f"""// servowatch: C_Lk with its baseline (C_Lk / leak_ratio) and alarm levels
export const inputs = ["{est}", "{health}"];
export const output = "{LEAK_SCRIPT}";
const LEAK_RAISE = {raise_!r}; // MonitorConfig.alarms.leak_raise (x baseline)
const LEAK_CLEAR = {clear!r}; // MonitorConfig.alarms.leak_clear
let leakRatio: number | undefined;
type Out = {{ c_lk: number; c_lk0: number; leak_raise: number; leak_clear: number }};
export default function script(event: {{ topic: string; message: any }}): Out | undefined {{
  if (event.topic === "{health}") {{
    const r = event.message.leak_ratio;
    if (typeof r === "number" && r > 0) leakRatio = r;
    return undefined;
  }}
  const c = event.message.c_lk;
  if (typeof c !== "number" || leakRatio === undefined) return undefined;
  const c0 = c / leakRatio;
  return {{ c_lk: c, c_lk0: c0, leak_raise: LEAK_RAISE * c0, leak_clear: LEAK_CLEAR * c0 }};
}}
"""


def _nis_script(res: str, band: list[tuple[float, float]]) -> str:
    table = json.dumps([[round(lo, 6), round(hi, 6)] for lo, hi in band])
    return f"""// servowatch: NIS and its two-sided 95 % chi-square band for the row's dof
export const inputs = ["{res}"];
export const output = "{NIS_SCRIPT}";
const BAND: number[][] = {table}; // BAND[dof] = [lo, hi]
type Out = {{ nis: number; dof: number; lo: number; hi: number }};
export default function script(event: {{ message: any }}): Out | undefined {{
  const nis = event.message.nis;
  const dof = event.message.nis_dof;
  if (typeof nis !== "number" || typeof dof !== "number" || !(dof >= 1 && dof < BAND.length))
    return undefined;
  return {{ nis, dof, lo: BAND[dof][0], hi: BAND[dof][1] }};
}}
"""


def nis_band(max_dof: int = 8) -> list[tuple[float, float]]:
    """[dof] -> the two-sided 95 % chi-square band (dof 0: none)."""
    from scipy.stats import chi2

    return [(0.0, 0.0)] + [(chi2.ppf(0.025, d), chi2.ppf(0.975, d)) for d in range(1, max_dof + 1)]


def build(aircraft: str, actuator: str) -> dict:
    """The layout as a dict (Foxglove's layout JSON)."""
    import foxglove.layouts as fl

    from service.monitor import MonitorConfig
    from service.wire import messages as m

    t = {leaf: m.mcap_topic(aircraft, actuator, leaf) for leaf in
         ("est", "residual", "health", "events")}  # fmt: skip
    al = MonitorConfig().alarms

    def plot(title: str, series: list[tuple[str, str]], ylabel: str) -> fl.PlotPanel:
        return fl.PlotPanel(
            title=title,
            config=fl.PlotConfig(
                paths=[fl.PlotSeries(value=v, label=lab) for v, lab in series],
                show_legend=True, legend_display="top", y_axis_label=ylabel,
                x_axis_val="timestamp", is_synced=True,
            ),
        )  # fmt: skip

    c_lk = plot("C_Lk, its baseline and alarm levels", [
        (f"{LEAK_SCRIPT}.c_lk", "C_Lk"),
        (f"{LEAK_SCRIPT}.c_lk0", "baseline"),
        (f"{LEAK_SCRIPT}.leak_clear", f"clear ({al.leak_clear:g} x)"),
        (f"{LEAK_SCRIPT}.leak_raise", f"raise ({al.leak_raise:g} x)"),
    ], "m^3/s/Pa")  # fmt: skip
    p_sr = plot("P_SR", [(f"{t['est']}.p_sr", "P_SR")], "Pa")
    res_p = plot("Residuals: pressures", [
        (f"{t['residual']}.innov_{c}", c) for c in ("p1", "p2", "p_sr")], "Pa")  # fmt: skip
    res_x = plot("Residuals: positions", [
        (f"{t['residual']}.innov_{c}", c) for c in ("x_s", "x_j")], "m")  # fmt: skip
    nis = plot("NIS and its 95 % band", [
        (f"{NIS_SCRIPT}.nis", "NIS"), (f"{NIS_SCRIPT}.lo", "band low"),
        (f"{NIS_SCRIPT}.hi", "band high")], "")  # fmt: skip
    alarms = fl.StateTransitionsPanel(
        title="Alarms",
        config=fl.StateTransitionsConfig(
            paths=[fl.StateTransitionsSeries(value=f"{t['health']}.alarm_leak", label="leak"),
                   fl.StateTransitionsSeries(value=f"{t['health']}.alarm_supply",
                                             label="supply")],
        ),
    )  # fmt: skip
    events = fl.RawMessagesPanel(
        title="Alarm events", config=fl.RawMessagesConfig(topic_path=t["events"])
    )
    col = lambda *ps: fl.SplitContainer(  # noqa: E731
        direction="column", items=[fl.SplitItem(content=p) for p in ps]
    )
    layout = fl.Layout(
        content=fl.SplitContainer(
            direction="row",
            items=[
                fl.SplitItem(content=col(c_lk, p_sr, alarms)),
                fl.SplitItem(content=col(res_p, res_x, nis)),
                fl.SplitItem(proportion=0.5, content=events),
            ],
        ),
        user_scripts={
            "servowatch_leak": fl.UserScript(
                name="servowatch: C_Lk baseline and alarm levels",
                source_code=_leak_script(t["est"], t["health"], al.leak_raise, al.leak_clear),
            ),
            "servowatch_nis": fl.UserScript(
                name="servowatch: NIS band", source_code=_nis_script(t["residual"], nis_band())
            ),
        },
    )
    return json.loads(layout.to_json())


def layout_json(aircraft: str, actuator: str) -> str:
    """The layout of unit ``aircraft/actuator`` as the text of a Foxglove layout file."""
    return json.dumps(build(aircraft, actuator), indent=2) + "\n"
