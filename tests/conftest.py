"""Shared test configuration: a derandomised hypothesis profile."""

from hypothesis import settings

pytest_plugins = ["controller.testing.pytest_plugin"]

settings.register_profile("ci", derandomize=True, deadline=None, print_blob=True)
settings.load_profile("ci")
