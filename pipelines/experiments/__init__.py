"""The paper's experiments as recipes: plans of shipped commands, resumable, reported beside the paper's numbers."""
