"""Blocks every demo-conditioned policy shares: the model skeleton (trunk, frame embedding, action and
inverse-dynamics heads), attention, augmentation, encodings, the demo-conditioning layer and the policy
interface."""
