"""KUKA RSI Ethernet messages (XML over UDP) and the RSI Ethernet configuration file.

The controller sends one message per interpolation cycle::

    <Rob Type="KUKA">
      <RIst X=".." Y=".." Z=".." A=".." B=".." C=".."/>   actual TCP pose
      <RSol X=".." Y=".." Z=".." A=".." B=".." C=".."/>   setpoint TCP pose
      <AIPos A1=".." A2=".." ... A6=".."/>                  axis positions, deg
      <IPOC>123456</IPOC>                                    the cycle stamp (ms)
    </Rob>

and expects, within the cycle, ``<Sen Type="ImFree"><RKorr X=".." .. C=".."/><IPOC>123456</IPOC></Sen>``.
Poses: ``X Y Z`` mm, ``A B C`` deg with ``R = Rz(A) Ry(B) Rx(C)`` (KRL). The element names of the
correction and the ``Sen`` type come from the user's ``RSI_EthernetConfig.xml`` where given
(:func:`read_config`: ``<SENTYPE>`` and the ``<RECEIVE>`` elements ``Name.X`` .. ``Name.C``).
"""

from __future__ import annotations

import re
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np

__all__ = ["RobMessage", "RsiConfig", "RsiConfigWarning", "RsiMessageError", "format_rob", "format_sen", "ipoc_of", "parse_rob", "parse_sen", "read_config"]

_CART = ("X", "Y", "Z", "A", "B", "C")
_IPOC = re.compile(rb"<IPOC>\s*(\d{1,20})\s*</IPOC>")
# ASCII digits only: str.isdigit() and float() also take '²', Arabic-Indic digits and '1_0' (probe s42 AS: an
# IPOC of '1004²' passed isdigit(), int() raised outside the handler's catch and the bridge exited)
_INT = re.compile(r"\s*([0-9]{1,20})\s*")
_NUM = re.compile(r"\s*[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?\s*")
#: correction modes as written (RSI_ON(#RELATIVE) is KUKA's name of the incremental one) -> hykin's
_MODES = {"absolute": "absolute", "incremental": "incremental", "relative": "incremental"}


class RsiMessageError(ValueError):
    """A controller message hykin cannot use (one-line reason)."""


class RsiConfigWarning(UserWarning):
    """An RSI config that hykin can use, but with which the controller would not send what hykin needs."""


@dataclass(frozen=True)
class RsiConfig:
    """Names of an RSI Ethernet object. sen_type: ``<Sen Type=..>`` [ImFree]. korr_tag: the correction
    element [RKorr]. setpoint_tag / actual_tag / axes_tag: [RSol] / [RIst] / [AIPos]. mode:
    ``"absolute"`` (RKorr is the whole correction of this setpoint) or ``"incremental"`` (added to the
    sum of the corrections sent so far; ``"relative"``, KUKA's name, is taken as it) [absolute]. port / ip: from the file (informative)."""

    sen_type: str = "ImFree"  # any text: the value of the answer's Type attribute (escaped)
    korr_tag: str = "RKorr"
    setpoint_tag: str = "RSol"
    actual_tag: str = "RIst"
    axes_tag: str = "AIPos"
    mode: str = "absolute"
    port: int | None = None
    ip: str | None = None

    def __post_init__(self):
        mode = _MODES.get(str(self.mode).strip().lower())
        if mode is None:
            raise ValueError(f"RSI correction mode must be 'absolute' or 'incremental' (KUKA's #RELATIVE), got "
                             f"{self.mode!r}")
        object.__setattr__(self, "mode", mode)  # (frozen) 'relative' is stored as 'incremental'
        if not self.sen_type.strip() or any(ord(c) < 32 for c in self.sen_type):
            raise ValueError(f"RSI sen_type {self.sen_type!r} must be text without control characters")
        for name in ("korr_tag", "setpoint_tag", "actual_tag", "axes_tag"):
            if not re.fullmatch(r"[A-Za-z_][\w.\-]*", getattr(self, name)):
                raise ValueError(f"RSI {name} {getattr(self, name)!r} is not an XML name")


def read_config(path: str | Path, mode: str | None = None) -> RsiConfig:
    """Read an ``RSI_EthernetConfig.xml``: ``<CONFIG><SENTYPE>``, ``<IP_NUMBER>``, ``<PORT>``, and the
    correction element among ``<RECEIVE><ELEMENTS><ELEMENT TAG="Name.X" ../>`` (the one name that has
    all of ``X Y Z A B C``). ``mode`` overrides the file's ``<CONFIG><CORRMODE>`` (hykin's element:
    ``ABSOLUTE`` / ``INCREMENTAL``; RSI's own mode is the POSCORR object's, which must agree).
    ValueError naming the file and the element otherwise, also when ``<RECEIVE>`` lists elements but no
    Cartesian correction (the controller would drop hykin's). :class:`RsiConfigWarning` when ``<SEND>``
    lists elements but not ``DEF_RSol`` / ``DEF_AIPos`` (the setpoint and the axes every message needs)."""
    p = Path(path)
    try:
        root = ET.parse(p).getroot()
    except (OSError, ET.ParseError) as e:
        raise ValueError(f"{p}: not a readable RSI Ethernet config ({type(e).__name__}: {e})") from None
    cfg = root.find("CONFIG")
    if cfg is None:
        raise ValueError(f"{p}: no <CONFIG> element (not an RSI Ethernet config)")
    kw: dict = {}
    if (t := cfg.findtext("SENTYPE")) is not None and t.strip():
        kw["sen_type"] = t.strip()
    if (t := cfg.findtext("IP_NUMBER")) is not None:
        kw["ip"] = t.strip()
    if (t := cfg.findtext("PORT")) is not None:
        if not t.strip().isdigit() or not 0 < int(t) < 65536:
            raise ValueError(f"{p}: <PORT> must be 1..65535, got {t.strip()!r}")
        kw["port"] = int(t)
    file_mode = (cfg.findtext("CORRMODE") or "").strip().lower() or None
    groups: dict = {}
    for el in root.findall("./RECEIVE/ELEMENTS/ELEMENT"):
        tag = el.get("TAG", "")
        name, _, comp = tag.rpartition(".")
        if name and comp in _CART:
            groups.setdefault(name, set()).add(comp)
    full = [n for n, comps in groups.items() if comps == set(_CART)]
    if len(full) > 1:
        raise ValueError(f"{p}: several correction elements with X..C in <RECEIVE>: {', '.join(full)}; keep one")
    if full:
        kw["korr_tag"] = full[0]
    elif groups:
        name, comps = next(iter(groups.items()))
        raise ValueError(f"{p}: <RECEIVE> element {name} lacks {', '.join(c for c in _CART if c not in comps)} (needs X Y Z A B C)")
    elif received := [el.get("TAG", "") for el in root.findall("./RECEIVE/ELEMENTS/ELEMENT")]:
        # the controller reads only what <RECEIVE> lists: a correction it does not list would be dropped
        # silently and the robot would run uncorrected
        raise ValueError(f"{p}: <RECEIVE> lists no Cartesian correction (elements {', '.join(received[:8])}); hykin rsi "
                         f"sends one: add <ELEMENT TAG=\"RKorr.X\" TYPE=\"DOUBLE\" INDX=\"..\" HOLDON=\"1\" /> .. RKorr.C "
                         f"and connect them to the POSCORR object")
    kw["mode"] = (mode or file_mode or "absolute")
    try:
        cfg = RsiConfig(**kw)
    except ValueError as e:
        raise ValueError(f"{p}: {e}") from None
    sent = {el.get("TAG", "") for el in root.findall("./SEND/ELEMENTS/ELEMENT")}
    if sent:  # the controller sends the DEF_ elements its <SEND> lists
        miss = [t for t in (cfg.setpoint_tag, cfg.axes_tag) if f"DEF_{t}" not in sent]
        if miss:
            warnings.warn(f"{p}: <SEND> does not list {', '.join('DEF_' + t for t in miss)}: hykin needs the setpoint "
                          f"(DEF_{cfg.setpoint_tag}) and the axis positions (DEF_{cfg.axes_tag}) in every message and "
                          f"ignores messages without them; add <ELEMENT TAG=\"DEF_..\" TYPE=\"DOUBLE\" INDX=\"INTERNAL\" />",
                          RsiConfigWarning, stacklevel=2)
    return cfg


@dataclass
class RobMessage:
    """One controller message: ``ipoc`` (int), ``setpoint`` / ``actual`` ``(6,)`` (X Y Z mm, A B C deg),
    ``axes_deg`` ``(n,)`` (A1..An)."""

    ipoc: int
    setpoint: np.ndarray
    actual: np.ndarray | None
    axes_deg: np.ndarray


def ipoc_of(data: bytes) -> int | None:
    """The ``<IPOC>`` of a message even when the rest cannot be parsed (None without one)."""
    m = _IPOC.search(data)
    return int(m.group(1)) if m else None


def _numbers(el, tag: str, names) -> np.ndarray:
    """The attributes ``names`` of element ``el`` as finite floats (RsiMessageError otherwise)."""
    try:
        texts = [el.attrib[k] for k in names]
    except KeyError as e:
        raise RsiMessageError(f"<{tag}> lacks attribute {e.args[0]}") from None
    for k, t in zip(names, texts):
        if not _NUM.fullmatch(t):
            raise RsiMessageError(f"<{tag}> {k}={t[:40]!r} is not a decimal number (NaN, inf or garbled)")
    v = np.array([float(t) for t in texts])
    if not np.isfinite(v).all():
        raise RsiMessageError(f"<{tag}> holds a number out of range")
    return v


def _cart(el, tag: str) -> np.ndarray:
    return _numbers(el, tag, _CART)


def parse_rob(data: bytes, cfg: RsiConfig, dof: int) -> RobMessage:
    """Parse a controller message (:class:`RsiMessageError` with the reason otherwise)."""
    if b"<!" in data:
        raise RsiMessageError("DOCTYPE/ENTITY declarations are not accepted")
    try:
        root = ET.fromstring(data)
    except ET.ParseError as e:
        raise RsiMessageError(f"not XML ({e})") from None
    if root.tag != "Rob":
        raise RsiMessageError(f"root element <{root.tag}>, expected <Rob>")
    ipoc_m = _INT.fullmatch(root.findtext("IPOC") or "")
    if ipoc_m is None:
        raise RsiMessageError("no integer <IPOC> (ASCII digits)")
    sp = root.find(cfg.setpoint_tag)
    if sp is None:
        raise RsiMessageError(f"no <{cfg.setpoint_tag}> (setpoint) element")
    ax = root.find(cfg.axes_tag)
    if ax is None:
        raise RsiMessageError(f"no <{cfg.axes_tag}> (axis positions) element")
    axes = _numbers(ax, cfg.axes_tag, [f"A{j + 1}" for j in range(dof)])
    act = root.find(cfg.actual_tag)
    return RobMessage(int(ipoc_m.group(1)), _cart(sp, cfg.setpoint_tag), None if act is None else _cart(act, cfg.actual_tag),
                      axes)


def format_sen(ipoc: int, korr: np.ndarray, cfg: RsiConfig) -> bytes:
    """The answer: correction ``korr`` ``(6,)`` (mm, deg) and the echoed ``ipoc``."""
    attrs = " ".join(f'{k}="{v:.5f}"' for k, v in zip(_CART, np.asarray(korr, dtype=np.float64).tolist()))
    sen = escape(cfg.sen_type, {'"': "&quot;"})
    return f'<Sen Type="{sen}"><{cfg.korr_tag} {attrs} /><IPOC>{int(ipoc)}</IPOC></Sen>'.encode()


def format_rob(ipoc: int, setpoint: np.ndarray, actual: np.ndarray, axes_deg: np.ndarray, cfg: RsiConfig) -> bytes:
    """A controller message (the simulated controller's side)."""
    def cart(tag, v):
        return f"<{tag} " + " ".join(f'{k}="{x:.6f}"' for k, x in zip(_CART, np.asarray(v).tolist())) + " />"

    axes = " ".join(f'A{j + 1}="{x:.6f}"' for j, x in enumerate(np.asarray(axes_deg).tolist()))
    return (f'<Rob Type="KUKA">{cart(cfg.actual_tag, actual)}{cart(cfg.setpoint_tag, setpoint)}'
            f'<{cfg.axes_tag} {axes} /><IPOC>{int(ipoc)}</IPOC></Rob>').encode()


def parse_sen(data: bytes, cfg: RsiConfig) -> tuple[int, np.ndarray]:
    """``(ipoc, korr (6,))`` of an answer (the simulated controller's side); RsiMessageError otherwise."""
    try:
        root = ET.fromstring(data)
    except ET.ParseError as e:
        raise RsiMessageError(f"not XML ({e})") from None
    k = root.find(cfg.korr_tag)
    ipoc_m = _INT.fullmatch(root.findtext("IPOC") or "")
    if root.tag != "Sen" or k is None or ipoc_m is None:
        raise RsiMessageError("not a <Sen> answer with a correction and an IPOC")
    return int(ipoc_m.group(1)), _cart(k, cfg.korr_tag)
