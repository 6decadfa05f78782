"""Many runs as data: variants (a preset plus overrides) over sequences, run through the
pipeline's ``run_slam`` and gathered as ``RunResult`` values."""
