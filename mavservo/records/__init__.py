"""What a run measured and wrote down: the paper's figures (L, sigma_L, reception intervals, R),
per-stage command latency and the run log directory."""
