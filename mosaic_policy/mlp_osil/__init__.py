"""mlp_osil policy: configuration_mlp_osil.py, modeling_mlp_osil.py, processor_mlp_osil.py."""
