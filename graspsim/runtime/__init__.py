"""Where long runs execute and how they resume: the executor (local cores or a Ray cluster)
and the resumable campaign folder (records appended as they come, a configuration that a
resume must match). Knows nothing of trials, scenes or detectors."""
