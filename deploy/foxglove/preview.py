"""Draw the panels of a Foxglove layout from an MCAP log with matplotlib (a stand-in picture
for docs: this is not Foxglove's rendering, it plots the same series from the same messages).

    .venv/bin/python deploy/foxglove/preview.py demo.mcap docs/img/foxglove_layout.png

The layout's Plot and StateTransitions panels are drawn in its row/column arrangement from
the log's topics; the two user-script topics of make_layout.py are computed here the same
way (C_Lk / leak_ratio as the baseline, the chi-square band of each row's dof); a RawMessages
panel lists the messages of its topic.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from make_layout import LEAK_SCRIPT, NIS_SCRIPT, nis_band  # noqa: E402


def _series(path: str, log: dict) -> tuple[np.ndarray, np.ndarray] | None:
    topic, _, field = path.rpartition(".")
    data = log.get(topic)
    if data is None or field not in data:
        return None
    return data["t"], data[field]


def _load(log_path: Path, topics: set[str], leak_raise: float, leak_clear: float) -> dict:
    """topic -> {"t": times, field: values} (script topics derived), events as rows."""
    from service.log import read_blocks, read_log

    out: dict[str, dict] = {}
    for blk in read_blocks(log_path, [t for t in topics if not t.endswith("/events")]):
        d = out.setdefault(blk.topic, {"t": [], **{n: [] for n in blk.names}})
        d["t"].append(blk.t)
        for k, n in enumerate(blk.names):
            d.setdefault(n, []).append(blk.values[:, k])
    log = {tp: {k: np.concatenate(v) for k, v in d.items()} for tp, d in out.items()}
    for tp in topics:
        if tp.endswith("/events"):
            log[tp] = {"rows": [(t, msg) for _, t, msg in read_log(log_path, [tp])]}
    est = next((v for k, v in log.items() if k.endswith("/est")), None)
    health = next((v for k, v in log.items() if k.endswith("/health")), None)
    res = next((v for k, v in log.items() if k.endswith("/residual")), None)
    if est is not None and health is not None:
        ratio = np.interp(est["t"], health["t"], health["leak_ratio"])
        with np.errstate(invalid="ignore", divide="ignore"):
            c0 = est["c_lk"] / ratio
        log[LEAK_SCRIPT] = {"t": est["t"], "c_lk": est["c_lk"], "c_lk0": c0,
                            "leak_raise": leak_raise * c0, "leak_clear": leak_clear * c0}  # fmt: skip
    if res is not None:
        band = np.array(nis_band())
        dof = np.clip(np.nan_to_num(res["nis_dof"]).astype(int), 0, len(band) - 1)
        log[NIS_SCRIPT] = {"t": res["t"], "nis": res["nis"], "lo": band[dof, 0],
                           "hi": band[dof, 1]}  # fmt: skip
    return log


def _panels(node: dict, box: tuple[float, float, float, float], out: list) -> None:
    """(panel, (x, y, w, h)) of each panel of a layout node, in figure fractions."""
    if node.get("type") == "split":
        items = node["items"]
        total = sum(i.get("proportion", 1) for i in items)
        x, y, w, h = box
        pos = 0.0
        for it in items:
            f = it.get("proportion", 1) / total
            if node.get("direction") == "row":
                sub = (x + pos * w, y, f * w, h)
            else:
                sub = (x, y + (1 - pos - f) * h, w, f * h)
            pos += f
            _panels(it["content"], sub, out)
    else:
        out.append((node, box))


def render(layout_path: Path, log_path: Path, png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from service.monitor import MonitorConfig

    layout = json.loads(layout_path.read_text())
    panels: list = []
    _panels(layout["content"], (0.0, 0.0, 1.0, 1.0), panels)
    topics = set()
    for p, _ in panels:
        c = p.get("config", {})
        for s in c.get("paths", []):
            topics.add(s["value"].rpartition(".")[0])
        if c.get("topicPath"):
            topics.add(c["topicPath"])
    base = {t.rpartition("/")[0] for t in topics if t.startswith("/fleet/")}
    topics |= {f"{b}/{leaf}" for b in base for leaf in ("est", "health", "residual")}
    al = MonitorConfig().alarms
    log = _load(log_path, topics, al.leak_raise, al.leak_clear)
    t0 = min((v["t"][0] for v in log.values() if "t" in v and len(v["t"])), default=0.0)
    fig = plt.figure(figsize=(16, 9), dpi=100)
    pad = 0.012
    for p, (x, y, w, h) in panels:
        ax = fig.add_axes((x + 3.5 * pad, y + 2.8 * pad, w - 4.5 * pad, h - 6.5 * pad))
        ax.set_title(p.get("title") or p.get("panelType"), fontsize=10, loc="left")
        c = p.get("config", {})
        kind = p.get("panelType")
        if kind == "Plot":
            for s in c.get("paths", []):
                xy = _series(s["value"], log)
                if xy is not None:
                    ax.plot(xy[0] - t0, xy[1], lw=0.9, label=s.get("label") or s["value"])
            ax.legend(fontsize=7, loc="upper left", ncol=4)
            ax.set_ylabel(c.get("yAxisLabel", ""), fontsize=8)
        elif kind == "StateTransitions":
            for k, s in enumerate(c.get("paths", [])):
                xy = _series(s["value"], log)
                if xy is None:
                    continue
                on = xy[1] > 0.5
                ax.fill_between(xy[0] - t0, k + 0.1, k + 0.9, where=on, color="tab:red",
                                step="post")  # fmt: skip
                ax.fill_between(xy[0] - t0, k + 0.1, k + 0.9, where=~on, color="tab:green",
                                alpha=0.35, step="post")  # fmt: skip
            labels = [s.get("label") or s["value"] for s in c.get("paths", [])]
            ax.set_yticks([k + 0.5 for k in range(len(labels))], labels)
            ax.set_ylim(0, len(labels))
        elif kind == "RawMessages":
            rows = log.get(c.get("topicPath"), {}).get("rows", [])
            text = "\n\n".join(json.dumps(msg, indent=1) for _, msg in rows[-4:]) or "(none)"
            ax.text(0.02, 0.98, text, va="top", family="monospace", fontsize=7,
                    transform=ax.transAxes)  # fmt: skip
            ax.set_xticks([])
            ax.set_yticks([])
        if kind in ("Plot", "StateTransitions"):
            ax.tick_params(labelsize=7)
            ax.set_xlabel("t [s] from the first sample", fontsize=7)
    fig.text(0.995, 0.003, f"{layout_path.name} drawn from {log_path.name} with matplotlib "
             "(not Foxglove's rendering)", fontsize=8, ha="right", va="bottom")  # fmt: skip
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("log", help="MCAP log (servowatch run, demo or replay --out)")
    p.add_argument("png")
    p.add_argument("--layout", default=str(Path(__file__).with_name("servowatch-layout.json")))
    a = p.parse_args(argv)
    render(Path(a.layout), Path(a.log), Path(a.png))
    print(f"wrote {a.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
