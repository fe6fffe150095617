"""robosuite's logger without the five warnings it prints on every import.

Importing robosuite 1.5 logs, on its own console handler: three lines about a missing private macro file
(``macros.py``), that ``robosuite_models`` (extra robots) is not installed, and that the mink whole-body IK
(for the GR1 humanoid) could not load. None of them concerns the suite, which uses robosuite's own Panda and
Sawyer with its OSC controller; yet every command, every collection worker and every evaluation worker
printed them, twice under LeRobot (whose root handler received them again by propagation).

:func:`quiet_robosuite_import` drops exactly those messages with a filter on robosuite's logger, installed
before robosuite is imported (``logging.getLogger`` hands robosuite the same logger object later), and stops
propagation to the root logger, because robosuite prints its records itself. Every other robosuite warning
or error still shows, once. It only touches :mod:`logging`, so :mod:`mosaic_data` installs it on import.
"""

from __future__ import annotations

import logging

ROBOSUITE_LOGGER_NAME = "robosuite_logs"
"""The logger robosuite's ``DefaultLogger`` configures and logs to (``robosuite.utils.log_utils``)."""

HARMLESS_IMPORT_WARNINGS: tuple[str, ...] = (
    "No private macro file found!",
    "It is recommended to use a private macro file",
    "To setup, run: python ",  # ... robosuite/scripts/setup_macros.py
    "Could not import robosuite_models.",
    "Could not load the mink-based whole-body IK.",
)
"""Beginnings of the warnings robosuite logs on import that do not apply to this suite."""


class HarmlessImportWarnings(logging.Filter):
    """Drops robosuite's known-harmless import warnings (:data:`HARMLESS_IMPORT_WARNINGS`), passes the rest."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith(HARMLESS_IMPORT_WARNINGS)


def quiet_robosuite_import() -> logging.Logger:
    """Install the filter and ``propagate=False`` on robosuite's logger (idempotent); returns that logger.

    Call it before robosuite is imported: the warnings are logged at import time.
    """
    logger = logging.getLogger(ROBOSUITE_LOGGER_NAME)
    if not any(isinstance(f, HarmlessImportWarnings) for f in logger.filters):
        logger.addFilter(HarmlessImportWarnings())
    # robosuite adds its own console handler to this logger; a root handler (LeRobot's, a worker's) would print
    # every record a second time.
    logger.propagate = False
    return logger
