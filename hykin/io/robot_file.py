"""Robot specs to :class:`Robot`: a preset name (the TOML files shipped in :mod:`hykin.presets`), a
TOML robot file or a URDF file."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from ..kinematics.robot import Robot, RobotFileError
from .modelfile import looks_like_model_file
from .robot_toml import load_robot_toml, robot_from_toml_text
from .urdf import load_urdf

__all__ = ["list_presets", "load_robot"]


def list_presets() -> list[str]:
    """Names of the robot presets shipped with hykin."""
    files = resources.files("hykin.presets").iterdir()
    return sorted(p.name[:-5] for p in files if p.name.endswith(".toml"))


def load_robot(spec: str | Path | Robot, base_link: str | None = None, tip_link: str | None = None) -> Robot:
    """Load a robot from a preset name, a TOML robot file or a URDF file.

    URDF files take their chain from ``base_link`` (default: the root link) to ``tip_link`` (default:
    the one tip; several tips are refused naming them), see :func:`hykin.io.urdf.load_urdf`.
    ``base_link``/``tip_link`` given for a robot that is not a URDF file raise :class:`RobotFileError`.
    """
    if (base_link is not None or tip_link is not None) and not str(spec).lower().endswith(".urdf"):
        what = "a robot object" if isinstance(spec, Robot) else str(spec)
        raise RobotFileError(f"{what}: --base/--tip (base_link/tip_link) name links of a URDF file; this is not one")
    if isinstance(spec, Robot):
        return spec
    s = str(spec)
    if s.lower() in list_presets():
        text = resources.files("hykin.presets").joinpath(s.lower() + ".toml").read_text(encoding="utf-8")
        return robot_from_toml_text(text, f"preset:{s.lower()}")
    p = Path(s)
    if p.is_file() and looks_like_model_file(p):  # else a binary read as text: "'utf-8' codec can't decode ..."
        named = p.suffix.lower() in (".toml", ".urdf")
        raise RobotFileError(f"{s}: this is a hykin model file (written by `hykin fit`), not a robot file" + (
            f"; it is read as one because it is named {p.suffix}: rename it .hykin" if named else
            "; a robot file (.toml/.urdf) or preset goes here, a model to fk, ik, evaluate, register, compensate"))
    if p.suffix.lower() == ".urdf":
        return load_urdf(p, base_link, tip_link)
    if p.suffix.lower() == ".toml" or p.exists():
        return load_robot_toml(p)
    raise RobotFileError(f"{s}: not a preset ({', '.join(list_presets())}), and no such file (for a virtual robot, "
                         "use the NAME.nominal.toml that `hykin simulate` writes beside its data)")
