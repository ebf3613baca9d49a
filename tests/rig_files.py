"""Rig recordings for the import tests: the HF bench's measured runs (``measured_run``: the
HF valve plus the scenario's sensor noise) written by each format's own library (nptdms's
``TdmsWriter``, asammdf's ``MDF.append``/``save``, pyarrow's Parquet and CSV writers) under a
test rig's channel names and units (mm, um, bar, psi, mA), and the maps that read them."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import numpy as np

C_LK0 = 2e-13
START = dt.datetime(2026, 3, 1, 8, 0, 0, tzinfo=dt.UTC)

# rig column -> (servowatch channel, unit, SI per unit)
RIG = {
    "PosDemand": ("x_cmd", "mm", 1e-3),
    "ValveCurrent": ("i", "mA", 1e-3),
    "SpoolPos": ("x_s", "um", 1e-6),
    "RamPos": ("x_j", "mm", 1e-3),
    "P_A": ("p1", "bar", 1e5),
    "P_B": ("p2", "bar", 1e5),
}


def run(kind: str, seconds: float = 4.0, ratio: float = 3.0) -> dict[str, np.ndarray]:
    """``healthy`` (healthy_noise) or ``leak`` (C_Lk ``ratio`` x nominal from the start, its
    own sensor seed): the measured signals in SI, ``t`` from 0."""
    from models.scenario import Profile
    from service.monitor.calibration import measured_run
    from service.sim.scenarios import load_scenario

    sc = load_scenario("healthy_noise")
    upd: dict = {"duration_s": seconds}
    if kind == "leak":
        upd["leak"] = Profile(initial=ratio * C_LK0)
        upd["sensors"] = sc.sensors.model_copy(update={"seed": 11})
    return measured_run(sc.model_copy(update=upd))[1]


def rig_columns(meas: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The rig's columns in its units."""
    return {col: meas[ch] / si for col, (ch, _, si) in RIG.items()}


def map_text(fmt: str, prefix: str = "", time: str = "") -> str:
    """A map of the rig's columns (``prefix``: ``"Rig/"`` for TDMS)."""
    lines = [f'format = "{fmt}"', time, "[actuator]", 'aircraft = "RIG1"', 'name = "rudder"',
             "[channels]"]  # fmt: skip
    for col, (ch, unit, _) in RIG.items():
        lines.append(f'{ch} = {{ column = "{prefix}{col}", unit = "{unit}" }}')
    return "\n".join(lines) + "\n"


def write_tdms(path: Path, meas: dict[str, np.ndarray]) -> Path:
    """One group ``Rig`` of waveform channels (``wf_start_time``, ``wf_increment``)."""
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    dt_s = float(meas["t"][1] - meas["t"][0])
    start = np.datetime64(START.replace(tzinfo=None), "us")
    chans = [
        ChannelObject("Rig", col, v, properties={"unit_string": RIG[col][1], "wf_increment": dt_s,
                                                 "wf_start_time": start, "wf_start_offset": 0.0})
        for col, v in rig_columns(meas).items()
    ]  # fmt: skip
    with TdmsWriter(path) as w:
        w.write_segment([RootObject({"name": "rig run"}), GroupObject("Rig"), *chans])
    return path


def write_mdf4(path: Path, meas: dict[str, np.ndarray], slow: dict | None = None) -> Path:
    """MDF 4.10 with the rig's channels in one group, the file's start time in its header;
    ``slow``: more signals ``{name: (t, values, unit)}`` appended as a group of their own."""
    from asammdf import MDF, Signal

    mdf = MDF(version="4.10")
    mdf.header.start_time = START
    sigs = [
        Signal(v, meas["t"], name=col, unit=RIG[col][1]) for col, v in rig_columns(meas).items()
    ]
    mdf.append(sigs, comment="rig")
    for name, (t, v, unit) in (slow or {}).items():
        mdf.append([Signal(v, t, name=name, unit=unit)], comment=name)
    mdf.save(path, overwrite=True)
    mdf.close()
    return path


def write_parquet(path: Path, meas: dict[str, np.ndarray]) -> Path:
    import pyarrow as pa
    import pyarrow.parquet as pq

    cols = {"Time": meas["t"], **rig_columns(meas)}
    pq.write_table(pa.table(cols), path, row_group_size=1000)
    return path


def write_csv(path: Path, meas: dict[str, np.ndarray]) -> Path:
    import pyarrow as pa
    import pyarrow.csv as pcsv

    cols = {"Time_ms": meas["t"] * 1e3, **rig_columns(meas)}
    pcsv.write_csv(pa.table(cols), path)
    return path
