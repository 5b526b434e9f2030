"""Real-time bridges: ``hykin rsi`` (KUKA RSI Ethernet), ``hykin egm`` (ABB Externally Guided Motion)."""

from __future__ import annotations

import inspect
from pathlib import Path

import typer

from .common import CLIError, PayloadKg, app, check_rt_priority, load_model, parse_axis_signs, with_payload

_LISTEN = typer.Option(..., "--listen", metavar="HOST:PORT", help="HOST:PORT to receive the controller's datagrams on.")
_CONTROLLER = typer.Option(None, "--controller", metavar="HOST:PORT", help="HOST:PORT of the controller: datagrams from anyone else are "
                           "dropped (default: the first sender of a valid message).")
_FRAME = typer.Option("auto", "--frame", metavar="measurement|base|auto", help="Setpoints in the controller's base frame are compensated in: measurement, "
                      "base or auto (as hykin compensate).")
_MAX_FAILURES = typer.Option(10, "--max-failures", metavar="N", help="Stop answering after this many consecutive cycles that could "
                             "not be compensated (the controller's timeout then stops the robot).")
_IDLE = typer.Option(0.0, "--idle-exit-s", metavar="S", help="Exit when no valid datagram came for this long after the first (0: never).")


_RT = typer.Option(20, "--rt-priority", metavar="N", help="Answer under SCHED_FIFO at this priority (1-99), so that other "
                   "processes cannot delay an answer; 0: normal priority. Without the right it runs at normal priority and says so.")
_SPIN = typer.Option(False, "--spin", help="Poll the socket without sleeping: no wake-up delay, at the cost of one busy core "
                     "(for a core set aside for the bridge).")
_MAX_MM = typer.Option(50.0, "--max-correction-mm", metavar="MM", help="A larger correction is a failure (answered neutrally).")
_MAX_DEG = typer.Option(5.0, "--max-correction-deg", metavar="DEG", help="A larger rotation correction is a failure.")
_MIS_MM = typer.Option(20.0, "--max-mismatch-mm", metavar="MM", help="The controller's actual pose (RSI RIst, EGM "
                       "feedBack.cartesian) farther than this from the nominal FK of its axes is a set-up error (axis "
                       "signs, robot file, tool or base frame): a failure (answered neutrally). Well above the nominal "
                       "model's own error of a few mm.")
_MIS_DEG = typer.Option(2.0, "--max-mismatch-deg", metavar="DEG", help="As --max-mismatch-mm, for the rotation.")
_SIGNS = typer.Option(None, "--axis-signs", metavar="S1,..,SN", help="Controller axis = sign × joint, e.g. -1,1,1,-1,1,-1 (default: from the "
                      "robot preset: -1,1,1,-1,1,-1 for kuka-kr*, else +1).")


def _bridge_setup(model: str, listen: str, controller: str | None, frame: str, max_failures: int, period_ms: float,
                  axis_signs: str | None, payload_kg: float | None, handler=None, message=None):
    """(model, compensator, bound socket, controller address, axis signs, controller-to-target frame).
    ``handler(mdl, comp, signs, base)``: builds the bridge's handler; with ``message`` (see :func:`_warm`)
    a throwaway one answers synthetic messages before the socket is bound."""
    import gc

    import numpy as np

    from ..compensation.branches import default_axis_signs
    from ..compensation.compensator import Compensator
    from ..compensation.targets import FRAMES
    from ..realtime.udp_bridge import bind_udp, parse_listen

    if frame not in FRAMES:
        raise CLIError(f"--frame must be one of {', '.join(FRAMES)}, got {frame!r}")
    if max_failures < 1:
        raise CLIError(f"--max-failures must be at least 1, got {max_failures}")
    if not 0 < period_ms <= 1000:
        raise CLIError(f"--period-ms must be in (0, 1000], got {period_ms}")
    try:
        host, port = parse_listen(listen)
    except ValueError as e:
        raise CLIError(str(e)) from None
    try:
        ctrl = parse_listen(controller) if controller else None
    except ValueError as e:
        raise CLIError(str(e).replace("--listen", "--controller")) from None
    mdl = with_payload(load_model(model), payload_kg)
    comp = Compensator(mdl, frame=frame)
    signs = parse_axis_signs(axis_signs, mdl.nominal.dof)
    signs = default_axis_signs(mdl.nominal) if signs is None else signs
    base = mdl.nominal.base if comp.frame == "measurement" else np.eye(4)
    _warm(mdl, comp, None if handler is None else lambda: handler(mdl, comp, signs, base), message, signs)
    # the loaded model and libraries are never scanned again (run_bridge freezes again: only what came since)
    gc.collect()
    gc.freeze()
    try:
        sock = bind_udp(host, port)
    except OSError as e:
        raise CLIError(f"--listen {listen}: cannot bind ({e.strerror or e})") from None
    return mdl, comp, sock, ctrl, signs, base


def _warm(mdl, comp, handler=None, message=None, signs=None) -> None:
    """Before the socket is bound and the banner printed, so that the controller's first cycle is answered
    in time: one step (probe s41 AH: the first answer left 0.2-5 s after the banner, while the compiled
    kernels loaded; an incremental first answer that late is never applied), then the whole per-message
    path: ``handler()`` (a throwaway handler like the bridge's) answers ``message(k, T, axes_deg)``, the
    controller's message of cycle ``k`` (0, 1) at the pose ``T`` ``(4, 4)`` (m, controller base frame)
    of the nominal robot at axes ``axes_deg`` (probe s42 AT: the first answer still left 130-245 ms after
    the banner: protobuf's import, the first FK, conversions). A failure here only means the first real
    cycle warms instead."""
    import warnings

    import numpy as np

    from ..geometry import se3

    nom = mdl.nominal
    q = np.clip(np.zeros(nom.dof), nom.lower, nom.upper)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            T = np.asarray(mdl.predict(q), dtype=np.float64)
            comp.step(T if comp.frame == "measurement" else se3.invert(nom.base) @ T, q)
            if handler is not None and message is not None:
                # away from the zero pose (a wrist singularity on most robots): a step that converges
                lo, hi = np.asarray(nom.lower, dtype=np.float64), np.asarray(nom.upper, dtype=np.float64)
                q = np.where(np.isfinite(lo) & np.isfinite(hi), lo + 0.4 * (hi - lo), 0.3)
                h, T = handler(), _nominal_fk(nom)(q)
                for k in range(2):
                    h(message(k, T, np.degrees(q * np.asarray(signs, dtype=np.float64))))
    except Exception:  # noqa: BLE001 - warming is optional
        pass


def _checked(h, actual: str, joints: str) -> str:
    """The exit line's clause on the check of the controller's actual pose (field ``actual``) against the
    nominal FK of its axes (field ``joints``) by handler ``h``."""
    if not h.mismatch_checked:
        return f"; {actual} not sent: not checked"
    return (f"; {actual} checked in {h.mismatch_checked} cycles (largest gap to FK({joints}) "
            f"{h.mismatch_max[0]:.3g} mm / {h.mismatch_max[1]:.3g} deg)")


def _nominal_fk(nominal):
    """``q -> (4, 4)``: the nominal TCP pose in the controller's base frame (what RIst / feedBack.cartesian hold)."""
    import numpy as np

    from ..geometry import se3
    from ..kinematics.fk import fk

    base_inv = se3.invert(np.asarray(nominal.base, dtype=np.float64))
    return lambda q: base_inv @ fk(nominal, np.asarray(q, dtype=np.float64))


def _serve(name: str, sock, handler, period_ms: float, max_failures: int, ctrl, idle_exit_s: float, rt_priority: int,
           spin: bool, extra=None) -> None:
    from ..realtime.udp_bridge import raise_priority, run_bridge

    if spin:  # a SCHED_FIFO thread that never sleeps is throttled by the kernel (sched_rt_runtime_us): pauses
        typer.echo(f"hykin {name}: polling without sleeping (--spin), at normal priority")
    else:
        typer.echo(f"hykin {name}: {raise_priority(rt_priority)}")
    with sock:
        st = run_bridge(sock, handler, period_s=period_ms / 1e3, max_failures=max_failures, controller=ctrl,
                        idle_exit_s=idle_exit_s, spin=spin)
    typer.echo(f"hykin {name}: {st.stopped}; {st.summary()}{extra() if extra else ''}")
    if "consecutive failures" in st.stopped:
        raise typer.Exit(3)


def _bridge_command(name: str, period_help: str, extra: tuple = ()):
    """Register ``hykin NAME`` with the options every bridge has (model, --listen, --controller, --frame,
    --axis-signs, --period-ms, --max-failures, --max-correction-*, --idle-exit-s) after its own
    ``extra`` ``(name, type, typer.Option)`` triples; the decorated function gets them all as keywords."""
    common = (("model", str, typer.Argument(..., metavar="MODEL", help="Model file (hykin fit).")),
              ("listen", str, _LISTEN)) + tuple(extra) + (
        ("controller", str | None, _CONTROLLER), ("frame", str, _FRAME), ("axis_signs", str | None, _SIGNS),
        ("period_ms", float, typer.Option(4.0, "--period-ms", metavar="MS", help=period_help)),
        ("max_failures", int, _MAX_FAILURES), ("max_correction_mm", float, _MAX_MM),
        ("max_correction_deg", float, _MAX_DEG), ("max_mismatch_mm", float, _MIS_MM), ("max_mismatch_deg", float, _MIS_DEG),
        ("idle_exit_s", float, _IDLE), ("rt_priority", int, _RT),
        ("spin", bool, _SPIN), ("payload_kg", float | None, PayloadKg))

    def register(fn):
        def cmd(**kw) -> None:
            check_rt_priority(kw["rt_priority"])  # before the model is loaded and the socket bound
            from ..realtime.udp_bridge import check_limits

            try:
                check_limits(**{k: kw[k] for k in ("max_correction_mm", "max_correction_deg", "max_mismatch_mm",
                                                    "max_mismatch_deg", "idle_exit_s")})
            except ValueError as e:
                raise CLIError(str(e)) from None
            fn(**kw)

        cmd.__name__, cmd.__doc__ = f"{name}_cmd", fn.__doc__
        cmd.__annotations__ = {n: t for n, t, _ in common} | {"return": None}
        cmd.__signature__ = inspect.Signature(
            [inspect.Parameter(n, inspect.Parameter.KEYWORD_ONLY, default=d, annotation=t) for n, t, d in common])
        app.command(name)(cmd)
        return fn

    return register


@_bridge_command("rsi", "RSI cycle, ms (4 or 12): answers later than this count as late.", (
    ("config", Path | None, typer.Option(None, "--config", metavar="FILE", help="RSI_EthernetConfig.xml: tag names "
                                         "(SENTYPE, the correction element) and <CORRMODE>.")),
    ("mode", str | None, typer.Option(None, "--mode", metavar="absolute|incremental", help="absolute or incremental "
                                      "correction ('relative', KUKA's #RELATIVE, is incremental; default: the config's, else "
                                      "absolute); must match RSI's POSCORR object.")),
    ("rist_lag_cycles", int, typer.Option(4, "--rist-lag-cycles", metavar="N", help="Incremental mode: RIst may show "
                                          "the command of up to N cycles before the last (a servo delay; 0..25). A "
                                          "lost answer is taken only after N+1 cycles; a larger lag is taken for "
                                          "lost answers and the correction is sent again."))))
def rsi_cmd(model, listen, config, mode, rist_lag_cycles, controller, frame, axis_signs, period_ms, max_failures,
            max_correction_mm, max_correction_deg, max_mismatch_mm, max_mismatch_deg, idle_exit_s, rt_priority, spin,
            payload_kg) -> None:
    """KUKA RSI Ethernet peer: answers each <Rob> message with the RKorr that puts the real robot on the setpoint."""
    from ..realtime.rsi import MAX_RIST_LAG_CYCLES, RsiHandler
    import numpy as np

    from ..compensation.krl import abc_from_matrix
    from ..realtime.rsi_xml import RsiConfig, format_rob, read_config

    if not 0 <= rist_lag_cycles <= MAX_RIST_LAG_CYCLES:
        raise CLIError(f"--rist-lag-cycles must be 0..{MAX_RIST_LAG_CYCLES}, got {rist_lag_cycles}")
    if mode is not None and mode.strip().lower() not in ("absolute", "incremental", "relative"):
        raise CLIError(f"--mode must be absolute or incremental (KUKA's #RELATIVE), got {mode!r}")
    try:
        cfg = read_config(config, mode) if config is not None else RsiConfig(mode=mode or "absolute")
    except ValueError as e:
        raise CLIError(str(e)) from None
    def handler(mdl, comp, signs, base):
        return RsiHandler(comp.step, base, mdl.nominal.dof, signs, cfg, period_ms, max_correction_mm,
                          max_correction_deg, _nominal_fk(mdl.nominal), max_mismatch_mm, max_mismatch_deg,
                          rist_lag_cycles)

    def message(k, T, axes_deg):
        pose = np.concatenate([T[:3, 3] * 1e3, abc_from_matrix(T[:3, :3], 0.0)])  # X Y Z mm, A B C deg
        return format_rob(1000 + k * max(int(round(period_ms)), 1), pose, pose, axes_deg, cfg)

    mdl, comp, sock, ctrl, signs, base = _bridge_setup(model, listen, controller, frame, max_failures, period_ms,
                                                       axis_signs, payload_kg, handler, message)
    h = handler(mdl, comp, signs, base)

    def extra() -> str:
        out = _checked(h, "RIst", "AIPos")
        if h.incremental:
            # (counts what RIst showed: a lost increment under 0.002 mm, or one RIst never shows, is not seen; probe AW D2)
            out += (f"; new RSI contexts {h.new_sessions}, re-synchronisations on answers RIst showed not applied "
                    f"{h.lost_answers} (RIst lag up to {h.rist_lag} cycles handled)")
        return out

    typer.echo(f"hykin rsi: {mdl.nominal.name} on udp://{listen} ({cfg.mode}, <Sen Type=\"{cfg.sen_type}\"> "
               f"<{cfg.korr_tag}>, frame {comp.frame})")
    _serve("rsi", sock, h, period_ms, max_failures, ctrl, idle_exit_s, rt_priority, spin, extra)


@_bridge_command("egm", "EGM cycle, ms: answers later than this count as late.")
def egm_cmd(model, listen, controller, frame, axis_signs, period_ms, max_failures, max_correction_mm, max_correction_deg,
            max_mismatch_mm, max_mismatch_deg, idle_exit_s, rt_priority, spin, payload_kg) -> None:
    """ABB EGM peer (pose guidance): answers each EgmRobot with the pose that puts the real robot on the planned one."""
    from ..realtime.egm import EgmHandler, format_robot

    def handler(mdl, comp, signs, base):
        return EgmHandler(comp.step, base, mdl.nominal.dof, signs, max_correction_mm, max_correction_deg,
                          _nominal_fk(mdl.nominal), max_mismatch_mm, max_mismatch_deg)

    def message(k, T, joints_deg):
        return format_robot(k + 1, k * max(int(round(period_ms)), 1), T, joints_deg, T)

    mdl, comp, sock, ctrl, signs, base = _bridge_setup(model, listen, controller, frame, max_failures, period_ms,
                                                       axis_signs, payload_kg, handler, message)
    h = handler(mdl, comp, signs, base)
    typer.echo(f"hykin egm: {mdl.nominal.name} on udp://{listen} (pose guidance, frame {comp.frame})")
    _serve("egm", sock, h, period_ms, max_failures, ctrl, idle_exit_s, rt_priority, spin,
           lambda: _checked(h, "feedBack.cartesian", "feedBack.joints"))
