"""mosaic_data: the MOSAIC simulated task suite, scripted experts and dataset tools.

Importing the package registers the gymnasium environments ``mosaic/<Task>-v0`` (robosuite loads only when
one is made) and quiets robosuite's harmless import warnings before anything here imports robosuite.
"""

from mosaic_data.tasks.robosuite_log import quiet_robosuite_import

quiet_robosuite_import()

from mosaic_data.envs import register_envs  # noqa: E402

register_envs()

__version__ = "0.1.0"
