"""Where the project's data files are: the EDS files (``eds/``) and the example bus
configurations (``examples/``).

In a source checkout (and an editable install) they are the top-level folders beside
``controller/``; a wheel installs the same files as ``controller/eds`` and
``controller/examples`` (``pyproject.toml`` maps them), keeping their relative layout, so the
``dcf: ../../eds/...`` paths inside ``examples/bus/*.yml`` resolve in both.
"""

from __future__ import annotations

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent


def data_path(*parts: str) -> Path:
    """The installed or checked-out path of a data file, e.g. ``data_path("eds", "x.eds")``.

    Raises FileNotFoundError naming both places looked in.
    """
    tried = []
    for base in (_PACKAGE, _PACKAGE.parent):  # wheel: inside the package; checkout: beside it
        p = base.joinpath(*parts)
        if p.exists():
            return p
        tried.append(str(p))
    raise FileNotFoundError(f"{'/'.join(parts)}: not found (looked in {', '.join(tried)}); "
                            "reinstall cantrack")
