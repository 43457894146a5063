"""Datasets made by the simulator and read back: the physics-labelled Cornell-format dataset,
the Cornell-sized stand-in, the copy for the CNN peers' loaders, and the offline benchmarks'
samples."""
