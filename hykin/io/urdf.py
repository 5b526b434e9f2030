"""URDF robots: load a serial chain from a URDF file, and export any :class:`Robot` as URDF.

* :func:`load_urdf` reads a URDF (standard library XML parser, no ROS needed) and returns a
  :class:`~hykin.kinematics.robot.Robot` with ``convention="urdf"``. The chain runs from ``base_link`` (default:
  the root link) to ``tip_link`` (default: the one tip; a URDF with several tips is refused naming
  them, see :func:`_default_tip`). Revolute, continuous and prismatic joints become robot joints; fixed joints are folded into
  the next movable joint's origin, or into ``tool`` after the last movable joint. Link frame i is the
  child link of movable joint i; its mass and centre of mass (``mass_kg``, ``com_m``, link frame i)
  combine that link's ``<inertial>`` with every link fixed to it further down the chain.
  Continuous joints get limits ``[-pi, pi]`` (every orientation once): sampling, network input
  normalisation and IK use that range (IK answers within it); measured joints outside it are
  accepted (the FK is 2π-periodic).
  ``<mimic joint multiplier offset>`` joints stay in the chain but are no robot input: their value is
  ``multiplier · leader + offset`` (:attr:`Robot.mimic`); ``Robot.dof`` counts the independent joints
  and ``lower``/``upper`` are theirs (a mimic joint's own ``<limit>`` is not used). The URDF text,
  base and tip links are kept in ``Robot.urdf`` so that :func:`calibrated_urdf_xml` can write a
  calibrated robot back into the maker's file.
* :func:`robot_to_urdf` writes any robot (DH, MDH or URDF) as a URDF serial chain with the same
  forward kinematics: ``base`` and ``tool`` become fixed joints, each joint i becomes a movable joint
  (child link ``joint_i_frame``, z = joint axis) followed by a fixed joint to ``link_i`` (hykin link
  frame i, which carries the link's mass and centre of mass). Used to cross-check with Pinocchio.
  Its joints have ``effort="0" velocity="0"``: a hykin robot has no effort or velocity limits (URDF
  requires both attributes; set them from the maker's data sheet, or in MoveIt's joint_limits.yaml).
* A URDF cannot carry joint compliance: :func:`compliance_gap_mm` measures how far the rigid FK it
  holds is from the compliant robot, and the writers name it (mean / max mm).

Units: URDF is SI (m, rad, kg). Errors are :class:`~hykin.kinematics.robot.RobotFileError` naming the file and
the element.
"""

from __future__ import annotations

import difflib
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ..geometry import se3
from ..kinematics.robot import Robot, RobotFileError

__all__ = ["calibrated_robot_urdf", "calibrated_urdf", "compliance_gap_mm", "load_urdf", "load_urdf_string", "robot_to_urdf"]

#: joint configurations (uniform, seed 0) the compliance a URDF leaves out is measured on (:func:`compliance_gap_mm`)
GAP_POSES = 1000

_MOVABLE = ("revolute", "continuous", "prismatic")


def _floats(text: str | None, n: int, where: str, default: tuple[float, ...]) -> np.ndarray:
    if text is None:
        return np.array(default, dtype=np.float64)
    parts = text.split()
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        raise RobotFileError(f"{where}: expected {n} numbers, got {text!r}") from None
    if len(vals) != n or not all(math.isfinite(v) for v in vals):
        raise RobotFileError(f"{where}: expected {n} finite numbers, got {text!r}")
    return np.array(vals)


def _float_attr(el: ET.Element, key: str, where: str, required: bool = True, default: float = 0.0) -> float:
    txt = el.get(key)
    if txt is None:
        if required:
            raise RobotFileError(f"{where}: missing attribute '{key}'")
        return default
    try:
        v = float(txt)
    except ValueError:
        raise RobotFileError(f"{where}: attribute '{key}' is not a number: {txt!r}") from None
    if not math.isfinite(v):
        raise RobotFileError(f"{where}: attribute '{key}' must be finite, got {txt!r}")
    return v


def _check_attrs(el: ET.Element, allowed, where: str) -> None:
    """An attribute outside ``allowed`` is a typo that would silently read as the default: refuse it."""
    import difflib

    for k in el.attrib:
        if k not in allowed:
            close = difflib.get_close_matches(k, list(allowed), n=1, cutoff=0.6)
            hint = f" (did you mean '{close[0]}'?)" if close else f" (expected {', '.join(allowed)})"
            raise RobotFileError(f"{where}: unknown attribute '{k}'{hint}")


def _origin(el: ET.Element | None, where: str) -> np.ndarray:
    """``<origin xyz rpy>`` of an element -> (4, 4) (identity when absent)."""
    o = None if el is None else el.find("origin")
    if o is None:
        return np.eye(4)
    _check_attrs(o, ("xyz", "rpy"), f"{where} <origin>")
    xyz = _floats(o.get("xyz"), 3, f"{where} <origin xyz>", (0.0, 0.0, 0.0))
    rpy = _floats(o.get("rpy"), 3, f"{where} <origin rpy>", (0.0, 0.0, 0.0))
    return se3.xyzrpy_to_transform(xyz, rpy)


def load_urdf(path: str | Path, base_link: str | None = None, tip_link: str | None = None) -> Robot:
    """Load the serial chain ``base_link`` -> ``tip_link`` of a URDF file as a :class:`Robot`.

    See the module docstring for defaults and conventions. Raises :class:`RobotFileError` naming the
    file and the element (joint/link) on malformed input.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise RobotFileError(f"{path}: file not found") from None
    return load_urdf_string(text, base_link, tip_link, where=str(path))


def load_urdf_string(
    text: str, base_link: str | None = None, tip_link: str | None = None, where: str = "<urdf>"
) -> Robot:
    """Like :func:`load_urdf` for URDF text; ``where`` names the source in error messages."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:
        raise RobotFileError(f"{where}: invalid XML: {e}") from None
    if root.tag != "robot":
        raise RobotFileError(f"{where}: root element must be <robot>, got <{root.tag}>")

    links: dict[str, ET.Element] = {}
    for el in root.findall("link"):
        nm = el.get("name")
        if not nm:
            raise RobotFileError(f"{where}: <link> without a name")
        links[nm] = el
    joints: dict[str, dict] = {}  # child link -> joint info
    for el in root.findall("joint"):
        jn = el.get("name")
        w = f"{where}: joint '{jn}'"
        if not jn:
            raise RobotFileError(f"{where}: <joint> without a name")
        jt = el.get("type")
        if jt not in _MOVABLE + ("fixed",):
            raise RobotFileError(f"{w}: type {jt!r} not supported (revolute, continuous, prismatic, fixed)")
        p, c = el.find("parent"), el.find("child")
        if p is None or p.get("link") is None:
            raise RobotFileError(f"{w}: missing <parent link=...>")
        if c is None or c.get("link") is None:
            raise RobotFileError(f"{w}: missing <child link=...>")
        parent, child = p.get("link"), c.get("link")
        for ln in (parent, child):
            if ln not in links:
                raise RobotFileError(f"{w}: link '{ln}' is not defined")
        if child in joints:
            raise RobotFileError(f"{w}: link '{child}' already has parent joint '{joints[child]['name']}'")
        info = {"name": jn, "type": jt, "parent": parent, "child": child, "origin": _origin(el, w)}
        if jt in _MOVABLE:
            ax = el.find("axis")
            if ax is not None:
                _check_attrs(ax, ("xyz",), f"{w} <axis>")
            axis = _floats(None if ax is None else ax.get("xyz"), 3, f"{w} <axis xyz>", (1.0, 0.0, 0.0))
            nrm = float(np.linalg.norm(axis))
            if nrm < 1e-12:
                raise RobotFileError(f"{w} <axis xyz>: axis must be non-zero")
            info["axis"] = axis / nrm
            lim = el.find("limit")
            if jt == "continuous":
                info["limits"] = (-math.pi, math.pi)
            else:
                if lim is None:
                    raise RobotFileError(f"{w}: missing <limit lower=... upper=...> (required for {jt} joints)")
                _check_attrs(lim, ("lower", "upper", "effort", "velocity"), f"{w} <limit>")
                if lim.get("lower") is None and lim.get("upper") is None:
                    raise RobotFileError(f"{w} <limit>: neither lower nor upper given (the joint would be locked at 0)")
                lo = _float_attr(lim, "lower", f"{w} <limit>", required=False, default=0.0)
                hi = _float_attr(lim, "upper", f"{w} <limit>", required=False, default=0.0)
                if lo > hi:
                    raise RobotFileError(f"{w} <limit>: lower > upper")
                info["limits"] = (lo, hi)
            mim = el.find("mimic")
            if mim is not None:
                _check_attrs(mim, ("joint", "multiplier", "offset"), f"{w} <mimic>")
                if not mim.get("joint"):
                    raise RobotFileError(f"{w} <mimic>: missing attribute 'joint'")
                info["mimic"] = (mim.get("joint"), _float_attr(mim, "multiplier", f"{w} <mimic>", False, 1.0),
                                 _float_attr(mim, "offset", f"{w} <mimic>", False, 0.0))
        joints[child] = info

    children: dict[str, list[str]] = {}
    for info in joints.values():
        children.setdefault(info["parent"], []).append(info["child"])
    if base_link is None:
        roots = [ln for ln in links if ln not in joints]
        if len(roots) != 1:
            raise RobotFileError(f"{where}: expected one root link, found {roots}; name base_link")
        base_link = roots[0]
    elif base_link not in links:
        raise RobotFileError(f"{where}: base_link '{base_link}' is not a link")

    def path_to(tip: str) -> list[dict]:
        chain, ln = [], tip
        while ln != base_link:
            if ln not in joints:
                raise RobotFileError(f"{where}: tip_link '{tip}' is not below base_link '{base_link}'")
            chain.append(joints[ln])
            ln = joints[ln]["parent"]
        return chain[::-1]

    if tip_link is None:
        tip_link = _default_tip(base_link, children, joints, path_to, where)
    elif tip_link not in links:
        leaves, tips = _tip_candidates(base_link, children, joints)
        close = difflib.get_close_matches(tip_link, list(links), n=1)
        raise RobotFileError(f"{where}: tip_link '{tip_link}' is not a link"
                             + (f" (did you mean '{close[0]}'?)" if close else "")
                             + f"; the tips below '{base_link}' are: {', '.join(tips or sorted(leaves))} "
                             "(--tip LINK on the command line)")
    chain = path_to(tip_link)

    def inertial(ln: str) -> tuple[float, np.ndarray]:
        el = links[ln].find("inertial")
        if el is None:
            return 0.0, np.zeros(3)
        w = f"{where}: link '{ln}' <inertial>"
        m_el = el.find("mass")
        m = 0.0 if m_el is None else _float_attr(m_el, "value", f"{w} <mass>")
        if m < 0:
            raise RobotFileError(f"{w} <mass>: must be >= 0")
        return m, _origin(el, w)[:3, 3]

    pending = np.eye(4)  # fixed transforms since the last movable joint's child frame
    origins, axes, types, lower, upper, masses, coms, names = [], [], [], [], [], [], [], []
    for j in chain:
        if j["type"] == "fixed":
            pending = pending @ j["origin"]
            if masses:  # a link rigidly attached to link frame i: merge its mass into link i
                m, c = inertial(j["child"])
                if m > 0:
                    c_i = (pending @ np.append(c, 1.0))[:3]
                    mt = masses[-1] + m
                    coms[-1] = (masses[-1] * coms[-1] + m * c_i) / mt
                    masses[-1] = mt
            continue
        origins.append(pending @ j["origin"])
        pending = np.eye(4)
        axes.append(j["axis"])
        types.append("prismatic" if j["type"] == "prismatic" else "revolute")
        lower.append(j["limits"][0])
        upper.append(j["limits"][1])
        m, c = inertial(j["child"])
        masses.append(m)
        coms.append(c)
        names.append(j["name"])
    if not origins:
        raise RobotFileError(f"{where}: no movable joint between '{base_link}' and '{tip_link}'")
    _check_metres(chain, where)
    mimic = _mimic_table([j for j in chain if j["type"] != "fixed"], {j["name"]: j for j in joints.values()},
                         base_link, tip_link, where)
    indep = [i for i in range(len(names)) if mimic[i, 0] < 0]
    lower, upper = [lower[i] for i in indep], [upper[i] for i in indep]
    origins = np.array(origins)
    xyz, rpy = se3.transform_to_xyzrpy(origins)
    n = len(origins)
    return Robot(
        name=root.get("name") or Path(where).stem,
        convention="urdf",
        a_m=np.zeros(n),
        alpha_rad=np.zeros(n),
        d_m=np.zeros(n),
        theta_rad=np.zeros(n),
        lower=lower,
        upper=upper,
        origin_xyz_m=xyz,
        origin_rpy_rad=rpy,
        axis=np.array(axes),
        joint_type=tuple(types),
        mass_kg=masses,
        com_m=np.array(coms),
        tool=pending,
        source=f"URDF {where}: chain {base_link} -> {tip_link}, joints {', '.join(names)}",
        mimic=mimic,
        joint_names=tuple(names),
        urdf={"xml": text, "base_link": base_link, "tip_link": tip_link,
              "continuous": " ".join(j["name"] for j in chain if j["type"] == "continuous")},
    )


#: Longest serial chain (m) a URDF may describe, summed over the joint origins from the first movable
#: joint to the tip. The longest serial machines are truck-mounted concrete-pump booms (up to ~100 m);
#: industrial arms reach 0.3-4.7 m; a chain written in mm reads 1000x too long, and the smallest arms
#: (desktop arms, 0.3-0.5 m of links) then add up to 300 m and more. URDF has no unit field (it is SI).
MAX_CHAIN_LENGTH_M = 120.0


def _check_metres(chain: list[dict], where: str) -> None:
    """Refuse a chain whose joint origins add up to more than :data:`MAX_CHAIN_LENGTH_M`: lengths
    written in mm. The origins before the first movable joint place the robot in its cell and are
    not counted; the message names the joint with the longest origin after it."""
    first = next(i for i, j in enumerate(chain) if j["type"] in _MOVABLE)
    arm = chain[first + 1:]
    if not arm:
        return
    lengths = np.array([np.linalg.norm(j["origin"][:3, 3]) for j in arm])
    total = float(lengths.sum())
    if total <= MAX_CHAIN_LENGTH_M:
        return
    j = arm[int(np.argmax(lengths))]
    xyz = " ".join(f"{v:g}" for v in j["origin"][:3, 3])
    raise RobotFileError(f"{where}: joint '{j['name']}' <origin xyz=\"{xyz}\">: the joint origins from "
                         f"'{chain[first]['name']}' to the tip add up to {total:.4g} m, implausible for a serial arm "
                         f"(at most {MAX_CHAIN_LENGTH_M:g} m): lengths look like mm (URDF uses metres); divide every "
                         "origin xyz (and prismatic limits) by 1000")


def _tip_candidates(base_link: str, children: dict, joints: dict) -> tuple[list[str], list[str]]:
    """``(leaves, tips)`` below ``base_link``: every leaf link, and the *tips*: leaves whose own branch
    (from the last link with several children) holds a movable joint (sorted)."""
    leaves, stack = [], [base_link]
    while stack:  # depth-first over the tree below base_link
        ln = stack.pop()
        kids = children.get(ln, [])
        if not kids:
            leaves.append(ln)
        stack.extend(kids)

    def own_branch_moves(leaf: str) -> bool:
        ln = leaf
        while ln != base_link and len(children.get(joints[ln]["parent"], [])) == 1:
            if joints[ln]["type"] in _MOVABLE:
                return True
            ln = joints[ln]["parent"]
        return ln != base_link and joints[ln]["type"] in _MOVABLE

    return leaves, sorted(lf for lf in leaves if own_branch_moves(lf))


def _default_tip(base_link: str, children: dict, joints: dict, path_to, where: str) -> str:
    """The chain end below ``base_link`` when no tip is named: the one tip (a leaf whose own branch holds a
    movable joint; a branch of fixed joints only, a camera bolted to a link, is a dead end), else the one dead
    end after the most movable joints. Several of either: refused naming them."""
    leaves, tips = _tip_candidates(base_link, children, joints)
    if len(leaves) == 1:
        return leaves[0]
    if len(tips) == 1:
        return tips[0]
    if len(tips) > 1:
        ends = _arm_end_links(tips, children, joints, path_to)
        also = f", or a link fixed to the arm's end: {', '.join(ends)}" if ends else ""
        raise RobotFileError(f"{where}: several tips ({', '.join(tips)}) below '{base_link}'; name tip_link "
                             f"(--tip LINK on the command line{also})")
    # not the longest path: frames bolted to one link differ by their offsets (s41 AI: 122 mm silently)
    score = {lf: sum(j["type"] in _MOVABLE for j in path_to(lf)) for lf in leaves}
    best = max(score.values())
    cands = sorted(lf for lf, s in score.items() if s == best)
    if len(cands) > 1:
        raise RobotFileError(f"{where}: several chain ends ({', '.join(cands)}) after the same joints; name tip_link "
                             f"(--tip LINK on the command line)")
    return cands[0]


def _arm_end_links(tips: list[str], children: dict, joints: dict, path_to) -> list[str]:
    """The links fixed to the arm's end that several ``tips`` (grippers' fingers) share: the links after the
    last movable joint common to all their chains, and the leaves fixed to those (a ``tcp``) — what a
    user means by the tip far more often than a finger (``flange``, ``tool0``, ``tcp``)."""
    paths = [path_to(t) for t in tips]
    common = []
    for js in zip(*paths):
        if any(j["name"] != js[0]["name"] for j in js):
            break
        common.append(js[0])
    last = max((i for i, j in enumerate(common) if j["type"] in _MOVABLE), default=None)
    if last is None:
        return []
    out = [j["child"] for j in common[last:]]
    stack = list(out)
    while stack:  # leaves reached through fixed joints only
        for c in children.get(stack.pop(), []):
            if joints[c]["type"] == "fixed" and c not in out:
                out.append(c)
                stack.append(c)
    return out


def _mimic_table(movable: list[dict], by_name: dict, base_link: str, tip_link: str, where: str) -> np.ndarray:
    """``(n, 3)`` ``[leader chain index or -1, multiplier, offset]`` of the chain's movable joints
    (:attr:`Robot.mimic`). A mimic of a mimic is resolved to the independent joint at its root; a
    leader off the chain, an unknown joint or a cycle is refused naming the joint."""
    index = {j["name"]: i for i, j in enumerate(movable)}
    out = np.zeros((len(movable), 3))
    out[:, 0] = -1.0
    for i, j in enumerate(movable):
        mult, off, cur, seen = 1.0, 0.0, j, {j["name"]}
        while "mimic" in cur:
            lead, m, o = cur["mimic"]
            w = f"{where}: joint '{cur['name']}' <mimic joint='{lead}'>"
            if lead not in by_name:
                raise RobotFileError(f"{w}: no joint of that name")
            if lead in seen:
                raise RobotFileError(f"{w}: mimic joints form a cycle")
            if by_name[lead]["type"] not in _MOVABLE:
                raise RobotFileError(f"{w}: the leader is a fixed joint")
            mult, off = mult * m, mult * o + off  # q = m (m_l q_root + o_l) + o
            cur = by_name[lead]
            seen.add(lead)
        if cur is j:
            continue
        if cur["name"] not in index:
            raise RobotFileError(f"{where}: joint '{j['name']}' mimics '{cur['name']}', which is not on the chain "
                                 f"'{base_link}' -> '{tip_link}' (choose --base/--tip to include it)")
        out[i] = (index[cur["name"]], mult, off)
    return out


def _fmt(v) -> str:
    return " ".join(repr(float(x)) for x in np.ravel(v))


def _origin_xml(T: np.ndarray) -> str:
    xyz, rpy = se3.transform_to_xyzrpy(np.asarray(T, dtype=np.float64))
    return f'<origin xyz="{_fmt(xyz)}" rpy="{_fmt(rpy)}"/>'


def robot_to_urdf(robot: Robot) -> str:
    """URDF text of ``robot`` as a serial chain with the same FK (see module docstring).

    Links: ``world`` -(fixed ``base``)-> ``base_link`` -(joint_1)-> ``joint_1_frame`` -(fixed)->
    ``link_1`` ... ``link_n`` -(fixed ``tool``)-> ``tcp``. Frame ``link_i`` equals hykin link frame i
    and ``joint_i_frame`` the joint frame i of :func:`hykin.kinematics.fk.fk_frames`.
    """
    from ..kinematics.chain import chain_of

    ch = chain_of(robot)
    lo, hi, mim = robot.lower, robot.upper, ""
    ex = robot.expansion()
    if ex is not None:  # chain-joint limits of mimic joints from their leaders'
        idx, mult, off = ex
        lo, hi = np.minimum(mult * lo[idx], mult * hi[idx]) + off, np.maximum(mult * lo[idx], mult * hi[idx]) + off
    out = [f'<?xml version="1.0"?>\n<robot name="{robot.name}">', '  <link name="world"/>', '  <link name="base_link"/>']
    out.append(
        f'  <joint name="base_joint" type="fixed"><parent link="world"/><child link="base_link"/>'
        f"{_origin_xml(robot.base)}</joint>"
    )
    parent = "base_link"
    for i in range(robot.n_chain):
        k = i + 1
        jt = "prismatic" if robot.joint_type[i] == "prismatic" else "revolute"
        out.append(f'  <link name="joint_{k}_frame"/>')
        inert = ""
        if robot.mass_kg[i] > 0:
            inert = (
                f'<inertial><origin xyz="{_fmt(robot.com_m[i])}" rpy="0 0 0"/><mass value="{float(robot.mass_kg[i])!r}"/>'
                '<inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial>'
            )
        out.append(f'  <link name="link_{k}">{inert}</link>')
        if robot.mimic is not None and robot.mimic[i, 0] >= 0:
            mim = (f'<mimic joint="joint_{int(robot.mimic[i, 0]) + 1}" multiplier="{float(robot.mimic[i, 1])!r}" '
                   f'offset="{float(robot.mimic[i, 2])!r}"/>')
        else:
            mim = ""
        out.append(
            f'  <joint name="joint_{k}" type="{jt}"><parent link="{parent}"/><child link="joint_{k}_frame"/>'
            f'{_origin_xml(ch.pre[i])}<axis xyz="0 0 1"/>'
            f'<limit lower="{float(lo[i])!r}" upper="{float(hi[i])!r}" effort="0" velocity="0"/>{mim}</joint>'
        )
        out.append(
            f'  <joint name="link_{k}_fixed" type="fixed"><parent link="joint_{k}_frame"/><child link="link_{k}"/>'
            f"{_origin_xml(ch.post[i])}</joint>"
        )
        parent = f"link_{k}"
    out.append('  <link name="tcp"/>')
    out.append(
        f'  <joint name="tool_joint" type="fixed"><parent link="{parent}"/><child link="tcp"/>'
        f"{_origin_xml(robot.tool)}</joint>"
    )
    out.append("</robot>\n")
    return "\n".join(out)


def calibrated_robot_urdf(robot: Robot) -> tuple[str, str]:
    """URDF text of a calibrated ``robot`` and what a URDF cannot carry (``""`` when nothing).

    A robot read from a URDF (``robot.urdf`` set) is written back into the maker's file: every joint,
    link, mimic tag, limit and side branch is kept; only the origins change: movable chain joint i gets
    ``inv(P_i) · O_i`` (``O_i`` the calibrated origin, ``P_i`` the fixed joints folded into it on
    loading), the last fixed joint before the tip takes the calibrated tool (a fixed joint to a new
    link ``<tip>_tcp`` when the chain ends in a movable joint), and a calibrated base frame becomes a
    fixed joint from a new root link ``measurement_frame`` (when ``base_link`` is the URDF's root).
    Loading the result with the same tip gives the same FK to rounding. Any other robot:
    :func:`robot_to_urdf`. Joint compliance (finite stiffness) cannot be carried; it is named, with how
    far the URDF's rigid FK is from the compliant robot (:func:`compliance_gap_mm`, :data:`GAP_POSES`
    joint configurations within the limits).
    """
    left = _compliance_note(robot, robot.random_joints(GAP_POSES, rng=0), "within the joint limits") \
        if robot.has_compliance else ""
    if robot.convention != "urdf" or not robot.urdf or robot.joint_names is None:
        return robot_to_urdf(robot.copy(stiffness_nm_per_rad=np.full(robot.n_chain, np.inf))), left
    return _patched_urdf(robot), left


def _set_origin(el: ET.Element, T: np.ndarray) -> None:
    o = el.find("origin")
    if o is None:
        o = ET.SubElement(el, "origin")
    xyz, rpy = se3.transform_to_xyzrpy(np.asarray(T, dtype=np.float64))
    o.attrib.clear()
    o.set("xyz", _fmt(xyz))
    o.set("rpy", _fmt(rpy))


def _patched_urdf(robot: Robot) -> str:
    u = robot.urdf
    root = ET.fromstring(u["xml"], parser=ET.XMLParser(target=ET.TreeBuilder(insert_comments=True)))  # keep comments
    by_child = {}
    for el in root.findall("joint"):
        by_child[el.find("child").get("link")] = el
    path, ln = [], u["tip_link"]
    while ln != u["base_link"]:
        path.append(by_child[ln])
        ln = path[-1].find("parent").get("link")
    path = path[::-1]
    O = se3.xyzrpy_to_transform(robot.origin_xyz_m, robot.origin_rpy_rad)
    names = list(robot.joint_names)
    pending, tail = np.eye(4), []
    for el in path:
        if el.get("type") == "fixed":
            pending = pending @ _origin(el, "")
            tail.append(el)
            continue
        i = names.index(el.get("name"))
        _set_origin(el, se3.invert(pending) @ O[i])
        pending, tail = np.eye(4), []
    if not np.allclose(robot.tool, pending, rtol=0.0, atol=0.0):
        if tail:
            before = np.eye(4)
            for el in tail[:-1]:
                before = before @ _origin(el, "")
            _set_origin(tail[-1], se3.invert(before) @ robot.tool)
        else:
            tcp = f"{u['tip_link']}_tcp"
            ET.SubElement(root, "link", name=tcp)
            j = ET.SubElement(root, "joint", name=f"{tcp}_joint", type="fixed")
            ET.SubElement(j, "parent", link=u["tip_link"])
            ET.SubElement(j, "child", link=tcp)
            _set_origin(j, robot.tool)
    if not np.array_equal(robot.base, np.eye(4)):
        if u["base_link"] in by_child:
            raise RobotFileError(f"robot {robot.name!r}: the calibrated base frame cannot be written above "
                                 f"'{u['base_link']}', which is not the URDF's root")
        ET.SubElement(root, "link", name="measurement_frame")
        j = ET.SubElement(root, "joint", name="measurement_frame_to_base", type="fixed")
        ET.SubElement(j, "parent", link="measurement_frame")
        ET.SubElement(j, "child", link=u["base_link"])
        _set_origin(j, robot.base)
    ET.indent(root)
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def calibrated_urdf(model) -> tuple[str, str]:
    """URDF of a fitted hybrid model's calibrated classical robot, and what a URDF cannot carry.

    The calibrated geometry and joint offsets go into the joint origins (:func:`calibrated_robot_urdf`:
    the maker's URDF for a robot read from one, else :func:`robot_to_urdf`), the calibrated base (with
    the model's registration frame ``frame_pre``) into a fixed joint above the base link and the tool
    (with ``frame_post``) into the last fixed joint. Joint compliance, thermal expansion and the
    residual networks are not representable; the second item names those the model has (joint
    compliance with how far the URDF's rigid FK is from the compliant robot, :func:`compliance_gap_mm`,
    over :data:`GAP_POSES` joint configurations in the model's training range).
    """
    rob = model.robot_
    rob = rob.copy(base=model.frame_pre_ @ rob.base, tool=rob.tool @ model.frame_post_, name=f"{rob.name}-calibrated",
                   stiffness_nm_per_rad=np.full(rob.n_chain, np.inf))
    left = []
    if model.robot_.has_compliance:
        lo, hi = np.asarray(model.support_lower_), np.asarray(model.support_upper_)
        q = lo + np.random.default_rng(0).random((GAP_POSES, len(lo))) * (hi - lo)
        left.append(_compliance_note(model.robot_, q, "in the model's training range", model.frame_pre_, model.frame_post_))
    th = getattr(model, "thermal_", None)
    if th is not None and th.coefficient_per_k != 0.0:
        left.append("thermal expansion")
    if getattr(model, "net_pos_", None) is not None:
        left.append("the residual networks")
    return calibrated_robot_urdf(rob)[0], ", ".join(left) or "nothing"


def compliance_gap_mm(robot: Robot, q: np.ndarray, pre=None, post=None) -> tuple[float, float]:
    """``(mean, max)`` mm between the TCP positions of ``robot`` with its joint compliance (at its
    payload, :func:`hykin.kinematics.compliance.compliant_fk`) and of its rigid FK (what a URDF holds),
    at joints ``q`` ``(N, dof)``; ``pre`` / ``post``: frames around both (a model's registration)."""
    from ..kinematics.compliance import compliant_fk
    from ..kinematics.fk import fk

    T = np.stack([compliant_fk(robot, q), fk(robot, q)])
    if pre is not None:
        T = np.asarray(pre) @ T
    if post is not None:
        T = T @ np.asarray(post)
    d = np.linalg.norm(T[0, :, :3, 3] - T[1, :, :3, 3], axis=1) * 1e3
    return float(d.mean()), float(d.max())


def _compliance_note(robot: Robot, q: np.ndarray, where: str, pre=None, post=None) -> str:
    mean, mx = compliance_gap_mm(robot, q, pre, post)
    return (f"joint compliance (the URDF's rigid FK is {mean:.3g} mm mean / {mx:.3g} mm max from the calibrated "
            f"compliant robot at its {robot.payload_kg:g} kg payload, over {len(q)} poses {where})")
