"""The test suite. A regular package, so that ``tests.helpers`` resolves to this folder and not to the top-level
``tests`` package a dependency (draccus) installs into site-packages; pytest puts the repository root first on
``sys.path`` (``pythonpath`` in pyproject.toml)."""
