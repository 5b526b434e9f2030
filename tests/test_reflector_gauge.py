"""Several reflectors on the tool measured without orientations: the tool's rotation is a choice of
frame (the robot file's), not a calibrated parameter; checked against the true robot written here."""

from __future__ import annotations

import numpy as np

from hykin.calibration.calibrate import calibrate, calibrated_fk
from hykin.geometry import se3
from hykin.io.robot_file import load_robot
from hykin.kinematics.fk import fk


def test_several_reflectors_without_orientations_keep_the_files_tool_rotation(tmp_path):
    """Three reflectors on the tool, positions only: where the tool body is comes from the data, how its
    TCP frame is turned does not (turning the frame and the offsets together moves no reflector). The
    calibrated tool keeps the robot file's rotation (as with one reflector) and the offsets are in that
    frame; the true tool's rotation was 15/40 deg off and used to come out 'identified' at tens of deg."""
    import csv

    from hykin.io.dataset_files import read_dataset

    nom = load_robot("ur5")
    E = se3.make_transform(se3.rotvec_to_matrix(np.radians([0.0, 15.0, 40.0])), np.array([0.012, -0.031, 0.118]))
    true = nom.copy(tool=E, base=se3.trans(2.0, -1.0, 0.5))
    q = nom.random_joints(100, 4, margin=0.1)
    T = fk(true, q)
    pts = np.array([[0.0, 0.0, 0.0], [0.04, 0.03, -0.01], [-0.05, 0.02, 0.01]])  # in the true TCP frame
    P = np.einsum("nab,kb->nka", T[:, :3, :3], pts) + T[:, None, :3, 3]
    P += 1e-5 * np.random.default_rng(0).standard_normal(P.shape)
    f = tmp_path / "three.csv"
    with open(f, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow([f"q{j + 1}" for j in range(6)] + ["x", "y", "z", "x2", "y2", "z2", "x3", "y3", "z3"])
        for qi, Pi in zip(q, P):
            w.writerow([*qi, *Pi.ravel()])
    res = calibrate(nom, read_dataset(f), compliance=False)
    assert not any(n.startswith("tool.r") for n in res.names)  # not a parameter of these data
    assert np.allclose(res.robot.tool[:3, :3], nom.tool[:3, :3], atol=1e-12)
    # the reflectors' offsets, seen from the file-rotated TCP frame, are the true ones turned by E's rotation
    ref = (pts[1:] @ E[:3, :3].T) @ nom.tool[:3, :3]
    assert np.abs(res.point_offsets_m[1:] - ref).max() < 1e-4
    q2 = nom.random_joints(50, 5, margin=0.1)
    assert np.abs(calibrated_fk(res.robot, q2)[:, :3, 3] - fk(true, q2)[:, :3, 3]).max() < 1e-4


def test_fk_does_not_pass_measured_reflector_columns_off_as_predictions(tmp_path, capsys):
    from cli_run import run

    f = tmp_path / "j.csv"
    f.write_text("q1,q2,q3,q4,q5,q6,x2,y2,z2,tag\n0.1,-1.2,1.3,-1.4,-1.5,0.2,9,9,9,7\n")
    code, _, err = run(["fk", "ur5", f, "-o", tmp_path / "o.csv"], capsys)
    assert code == 0, err
    head = (tmp_path / "o.csv").read_text().splitlines()[0].split(",")
    assert "x2" not in head and "tag" in head and head[6:9] == ["x", "y", "z"]
