"""tosil policy: configuration_tosil.py, modeling_tosil.py, processor_tosil.py."""
