"""MOSAIC policy: configuration_mosaic.py, modeling_mosaic.py, processor_mosaic.py, contrastive.py."""
