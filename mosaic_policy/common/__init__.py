"""Blocks every demo-conditioned policy shares: trunk, attention, action head, augmentation, encodings, the demo-conditioning layer and the policy interface."""
