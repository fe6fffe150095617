"""lstm_osil policy: configuration_lstm_osil.py, modeling_lstm_osil.py, processor_lstm_osil.py."""
