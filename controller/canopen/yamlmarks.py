"""Moved to :mod:`controller.yamlmarks` (shared with the scenario reader); kept as an alias."""

from ..yamlmarks import *  # noqa: F401,F403
from ..yamlmarks import MarkedList, MarkedMap, Section, item_section, load_marked, suggest  # noqa: F401
