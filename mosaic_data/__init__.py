"""mosaic_data: the MOSAIC simulated task suite, scripted experts and dataset tools.

Importing the package registers the gymnasium environments ``mosaic/<Task>-v0``.
"""

from mosaic_data.envs import register_envs

register_envs()

__version__ = "0.1.0"
