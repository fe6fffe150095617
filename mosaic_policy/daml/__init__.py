"""daml policy: configuration_daml.py, modeling_daml.py, processor_daml.py."""
