"""The offline simulator behind ``cantrack simulate``: a thin shell around the tracking core.

Python API::

    from controller.simulate import run_scenario, write_trace, format_summary, plot_result
    result = run_scenario("examples/linear_absolute.yaml")   # or a mapping with the same keys
    print(format_summary(result))
    write_trace(result, "trace.csv")
    plot_result(result, "trace.png")

Modules: ``scenario`` (YAML schema, loading, validation with file/line/key errors),
``master`` (master trajectories: segments, CSV, encoder + estimator), ``runner`` (the loop
around :class:`controller.tracking.Tracker` and the metrics), ``trace`` (CSV), ``summary``
(printed figures), ``plot`` (PNG), ``command`` (the ``cantrack simulate`` sub-command).
"""

from .runner import CycleResult, SimulationResult, run_scenario, simulate
from .scenario import Scenario, load_scenario
from .summary import format_summary
from .trace import write_trace


def plot_result(result, path, **kwargs):
    """Write the PNG plot of ``result`` (imports matplotlib on first use)."""
    from .plot import plot_result as _plot

    return _plot(result, path, **kwargs)


__all__ = ["CycleResult", "Scenario", "SimulationResult", "format_summary", "load_scenario",
           "plot_result", "run_scenario", "simulate", "write_trace"]
