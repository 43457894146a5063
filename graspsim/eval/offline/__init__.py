"""The offline benchmarks of the paper (recognition, detection, self-taught features) and of
the CNN peers, on image datasets, by object-wise cross-validation."""
