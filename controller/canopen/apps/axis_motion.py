"""Axis motion from Python: :func:`home`, :func:`move`, :func:`jog` (issue 7).

Each runs its job(s) (:mod:`~controller.canopen.apps.axis_jobs`) in a
:class:`~controller.canopen.apps.axis_controller.MotionController` on the embedded virtual
bus with simulated devices (stepped time, the default) or on a given transport (a real bus:
:class:`~controller.canopen.io.transport.RealtimeTransport`), and returns the
:class:`~controller.canopen.apps.axis_jobs.MotionReport` (s).  The names a caller needs with
them are exported here too.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from ...errors import ConfigError
from ..config.tracking import AxisConfig
from .axis_controller import MotionController, ProgressFn, check_max_time, run_job, run_jobs
from .axis_jobs import (
    DI_HOME,
    DI_NEG_LIMIT,
    DI_POS_LIMIT,
    DI_SLOW_DOWN,
    DriveHomingJob,
    GotoYJob,
    Job,
    JobResult,
    JogJob,
    MotionError,
    MotionReport,
    MoveJob,
    NoHomingJob,
    make_home_job,
)

__all__ = ["DI_HOME", "DI_NEG_LIMIT", "DI_POS_LIMIT", "DI_SLOW_DOWN", "DriveHomingJob",
           "GotoYJob", "Job", "JobResult", "JogJob", "MotionController", "MotionError", "MotionReport",
           "MoveJob", "NoHomingJob", "ProgressFn", "axis_config", "check_max_time", "home",
           "jog", "load_axes_config", "make_home_job", "move", "run_job", "run_jobs"]

def load_axes_config(config) -> Any:
    """``config`` (a bus.yml path or a loaded ControllerConfig) with its ``.tracking`` axes; a
    ConfigError naming the file when it has none."""
    from ..config import ControllerConfig, load_config
    cfg = config if isinstance(config, ControllerConfig) else load_config(Path(config))
    if cfg.tracking is None:
        raise ConfigError("no .tracking section: no axes", file=cfg.file)
    return cfg


def axis_config(cfg, name: str | None) -> AxisConfig:
    """The axis ``name`` of ``cfg`` (the first one for None); a MotionError listing the axes
    when there is none of that name."""
    axes = cfg.tracking.axes
    if name is None:
        return axes[0]
    for a in axes:
        if a.name == name:
            return a
    raise MotionError(f"no axis {name!r} (axes: {', '.join(a.name for a in axes)})")


def _run(cfg, jobs: Job | list[Job], transport=None, on_cycle: ProgressFn | None = None,
         max_time_s: float = 600.0, setup: Callable[[Any], None] | None = None,
         keep_trace: bool = False) -> list[MotionReport]:
    if transport is not None:
        ctl = MotionController(cfg, transport, jobs, on_cycle=on_cycle, keep_trace=keep_trace)
        return run_jobs(ctl, max_time_s)
    from ..slave.world import SimWorld
    with SimWorld(cfg) as world:
        if setup is not None:
            setup(world)
        ctl = MotionController(cfg, world.transport, jobs, on_cycle=on_cycle,
                               keep_trace=keep_trace)
        return run_jobs(ctl, max_time_s)


def move(config, axis: str, to: float, *, transport=None, on_cycle: ProgressFn | None = None,
         max_time_s: float = 600.0, setup=None) -> MotionReport:
    """Move ``axis`` to ``to`` [mm|deg, machine coordinate].  ``config``: bus.yml path or a
    loaded ControllerConfig; ``transport``: a real bus (default: the simulated devices, stepped)."""
    cfg = load_axes_config(config)
    ax = axis_config(cfg, axis)
    return _run(cfg, MoveJob(ax, cfg.period_s, to), transport, on_cycle, max_time_s,
                setup)[0]


def jog(config, axis: str, speed: float, time_s: float, *, transport=None,
        on_cycle: ProgressFn | None = None, max_time_s: float = 600.0,
        setup=None) -> MotionReport:
    """Jog ``axis`` at ``speed`` [mm/s] for ``time_s`` [s], then stop."""
    cfg = load_axes_config(config)
    ax = axis_config(cfg, axis)
    return _run(cfg, JogJob(ax, cfg.period_s, speed, time_s), transport, on_cycle,
                max_time_s, setup)[0]


def home(config, axis: str | Sequence[str] | None = None, *, transport=None,
         on_cycle: ProgressFn | None = None, max_time_s: float = 600.0,
         setup=None) -> list[MotionReport]:
    """Home ``axis`` (a name, several, or None = every axis with a ``homing:`` section, in
    the configured order) with its configured method, one after the other in one session;
    stops at the first failure (the later axes get no report).

    A named axis without a ``homing:`` section is an error (:class:`MotionError`, before
    anything moves): there is no default homing method.  With ``axis=None`` the axes
    without one are not homed; each gets a report with result ``SKIPPED`` (ok, says why),
    at the end of the list; an error if no axis has a ``homing:`` section."""
    cfg = load_axes_config(config)
    skipped: list[AxisConfig] = []
    if axis is None:
        names = [a.name for a in cfg.tracking.axes if a.homing is not None]
        skipped = [a for a in cfg.tracking.axes if a.homing is None]
        if not names:
            raise MotionError(f"no axis has a homing: section in {cfg.file}")
    elif isinstance(axis, str):
        names = [axis]
    else:
        names = list(axis)
    axes = [axis_config(cfg, name) for name in names]
    for ax in axes:
        if ax.homing is None:
            node_id = cfg.slaves[ax.node].node_id
            raise MotionError(f"axis {ax.name} (node {node_id}) has no homing: section "
                              f"in {cfg.file}")
    jobs = [make_home_job(ax, cfg.period_s) for ax in axes]
    check_max_time(max_time_s)
    reports = _run(cfg, jobs, transport, on_cycle, max_time_s, setup)
    for ax in skipped:
        reports.append(MotionReport(
            "home", ax.name, ok=True, result="SKIPPED",
            message=f"not homed: no homing: section in {cfg.file}"))
    return reports
