"""Closed-form IK accuracy on 10,000 random reachable targets per preset (issue 2's check).

Every returned solution's FK is compared with its target; the original joints must be among the
solutions (modulo 2π). Prints a markdown table.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hykin.geometry.se3 import pose_error
from hykin.io.robot_file import list_presets, load_robot
from hykin.kinematics.fk import fk
from hykin.kinematics.ik import ik_closed_form
from hykin.kinematics.ik_closed_form import has_closed_form


def main(n: int = 10_000) -> None:
    print(f"## Closed-form IK accuracy, {n:,} random targets per preset\n")
    print("| preset | family | solutions | max position error (m) | max angle error (rad) | original joints recovered | targets without solution |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for name in list_presets():
        r = load_robot(name)
        fam = has_closed_form(r)
        if not fam:
            print(f"| {name} | none ({r.dof} dof: numerical IK) | | | | | |")
            continue
        q = r.random_joints(n, 7)
        T = fk(r, q)
        sol = ik_closed_form(r, T)
        v = sol.valid
        pe, ae = pose_error(fk(r, sol.q[v]), np.repeat(T, v.sum(1), 0))
        d = np.abs((sol.q - q[:, None, :] + np.pi) % (2 * np.pi) - np.pi).max(-1)
        rec = np.where(v, d, np.inf).min(1) < 1e-6
        print(
            f"| {name} | {fam} | {int(v.sum()):,} | {pe.max() / 1e3:.2e} | {np.radians(ae.max()):.2e} | "
            f"{100 * rec.mean():.2f} % | {int((~v.any(1)).sum())} |"
        )


if __name__ == "__main__":
    main()
