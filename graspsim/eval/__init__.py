"""Evaluation: simulated grasp trials and clutter-removal rounds with any detector, their
summaries and statistics, paired comparisons, scoring a dataset's predictions by physics, and
(:mod:`graspsim.eval.offline`) the paper's offline benchmarks."""
