"""Scenario files (TOML) that a user opens and copies: ``paper/`` (section 4's runs), ``examples/``,
``sweeps/``. The code that reads and runs them is :mod:`tapmuscle.cosim`. This folder is installed as
the data package ``tapmuscle.scenario_files`` (pyproject.toml), so an installed tapmuscle finds them
without the source tree."""
