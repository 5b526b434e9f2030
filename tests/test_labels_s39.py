"""Label columns (station, tool, pose_id, pose) are text as written: "01" and "1" are two stations, tool
"007" stays "007" -- through `hykin import table` (kept columns) and `read_dataset`. Plain numbers read as
before ("2.0" -> "2")."""

from __future__ import annotations

import numpy as np
import pytest
from cli_run import run

from hykin.io.dataset import Dataset, DatasetError, row_labels
from hykin.io.dataset_files import read_dataset, write_dataset
from hykin.measure.table_import import import_table
from hykin.measure.table_map import table_map_from_dict

STATIONS = ["1", "01", "01", "1", "02", "01"]
TOOLS = ["007", "007", "T1", "007", "T1", "007"]
POSES = ["P01", "1", "01", "001", "1", "P01"]


def _table(tmp_path):
    rows = []
    for k, (s, t, pid) in enumerate(zip(STATIONS, TOOLS, POSES)):
        rows.append([f"{0.1 * (j + k):.3f}" for j in range(6)] + [f"{0.5 + 0.1 * k:.3f}", f"{0.2 * k:.3f}", "0.3", s, t, pid])
    p = tmp_path / "st.csv"
    p.write_text("q1,q2,q3,q4,q5,q6,x,y,z,Standpunkt,Werkzeug,Pose\n" + "\n".join(",".join(r) for r in rows) + "\n")
    return p


def test_import_keeps_station_tool_and_pose_labels_as_written(tmp_path, capsys):
    p = _table(tmp_path)
    m = {"joints": "q1..q6", "position": ["x", "y", "z"],
         "keep": {"Standpunkt": "station", "Werkzeug": "tool", "Pose": "pose_id"}}
    ds = import_table(p, table_map_from_dict(m))
    assert ds.extra["station"].tolist() == STATIONS
    assert ds.extra["tool"].tolist() == TOOLS and ds.extra["pose_id"].tolist() == POSES
    assert sorted(set(row_labels(ds, "station"))) == ["01", "02", "1"]  # "01" and "1" are two stations
    # through the CLI and back: the file holds the labels as written, read_dataset keeps them
    mp = tmp_path / "st.toml"
    mp.write_text('joints = "q1..q6"\nposition = ["x", "y", "z"]\n'
                  'keep = { "Standpunkt" = "station", "Werkzeug" = "tool", "Pose" = "pose_id" }\n')
    out = tmp_path / "o.csv"
    code, _, se = run(["import", "table", p, "--map", mp, "-o", out], capsys)
    assert code == 0, se
    lines = out.read_text().splitlines()
    assert [ln.split(",")[-3:] for ln in lines[1:]] == [list(r) for r in zip(STATIONS, TOOLS, POSES)]
    back = read_dataset(out)
    assert row_labels(back, "station").tolist() == STATIONS and row_labels(back, "tool").tolist() == TOOLS
    assert back.extra["pose_id"].tolist() == POSES


def test_read_dataset_keeps_leading_zero_labels_and_plain_numbers_as_before(tmp_path):
    p = tmp_path / "d.csv"
    body = [f"{0.1 * k},{0.2 * k},{0.5 + 0.1 * k},{0.1 * k},0.3,{s},{t}"
            for k, (s, t) in enumerate(zip(["01", "1", "01", "2.0", "2", " 01 "], ["007", "7", "7.0", "007", "7", "7"]))]
    p.write_text("q1,q2,x,y,z,station,tool\n" + "\n".join(body) + "\n")
    ds = read_dataset(p)
    assert row_labels(ds, "station").tolist() == ["01", "1", "01", "2", "2", "01"]
    assert row_labels(ds, "tool").tolist() == ["007", "7", "7", "007", "7", "7"]
    # files without leading zeros read as before: numbers "1", "2" -> labels "1", "2"
    q = tmp_path / "n.csv"
    q.write_text("q1,x,y,z,station\n" + "\n".join(f"{0.1 * k},{0.5 + 0.1 * k},0.1,0.3,{1 + k % 2}" for k in range(4)) + "\n")
    assert row_labels(read_dataset(q), "station").tolist() == ["1", "2", "1", "2"]
    # a non-label extra column is still numeric
    r = tmp_path / "e.csv"
    r.write_text("q1,x,y,z,temp\n0.1,0.5,0.1,0.3,021\n0.2,0.6,0.1,0.3,22\n")
    assert read_dataset(r).extra["temp"].dtype.kind == "f"


def test_labels_roundtrip_write_read_csv_and_parquet(tmp_path):
    pytest.importorskip("pyarrow")
    ds = Dataset(q=np.zeros((4, 1)) + np.arange(4)[:, None] * 0.1, xyz_m=np.c_[np.arange(4) * 0.1, np.ones(4), np.ones(4)],
                 extra={"station": np.array(["01", "1", "01", "1"]), "tool": np.array(["007"] * 4)})
    for suffix in ("csv", "parquet"):
        p = tmp_path / f"d.{suffix}"
        write_dataset(ds, p)
        back = read_dataset(p)
        assert row_labels(back, "station").tolist() == ["01", "1", "01", "1"]
        assert row_labels(back, "tool").tolist() == ["007"] * 4


def test_nan_text_label_is_refused_like_an_empty_one():
    bad = Dataset(q=np.zeros((2, 1)), xyz_m=np.zeros((2, 3)), extra={"station": np.array(["01", "nan"])}, source="f.csv")
    with pytest.raises(DatasetError, match="f.csv, row 2 .*column 'station'"):
        row_labels(bad, "station")
