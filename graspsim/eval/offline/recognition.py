"""The paper's recognition benchmark (Table 1, Figure 5): rectangle recognition by
nested cross-validation of every learner and encoder on a Cornell or Jacquard folder
(``graspsim benchmark recognition``).
"""

from __future__ import annotations

import functools
import json
import logging
from collections import Counter

from dlsr import recognition as rec
from dlsr.features import ENCODERS, LEARNERS
from dlsr.patches import load_patch_file
from dlsr.records import file_errors, read_json

from ...data.samples import load_samples

__all__ = ["recognition_benchmark", "recognition_choice"]

log = logging.getLogger(__name__)


def recognition_benchmark(
    data, format: str, out, scale=None, mapping=None, learners=None, encoders=None,
    n_atoms=300, n_patches=100_000, split="image", n_folds=5, inner_folds=5,
    paper_grid=False, whiten=True, extra_patches=None, max_rectangles=None, figure5=False,
    n_jobs=1, seed=0, progress=True, executor=None,
) -> dict:
    """Load ``data`` and run :func:`dlsr.recognition.run_recognition_benchmark`.

    With ``executor`` (a :class:`graspsim.runtime.executor.Executor`: local processes or a
    Ray cluster), its (learner, outer fold) tasks run where and on as many workers as the
    executor says (``n_jobs`` is then ignored); the results do not depend on it.
    """
    extra = None
    if extra_patches is not None:  # first: a bad file is reported before any long work

        extra = load_patch_file(extra_patches)
    samples = load_samples(data, format, scale, mapping)
    rd = rec.recognition_data(samples, random_state=seed, max_rectangles=max_rectangles,
                              subset_random_state=seed)
    log.info("%d rectangles (%d positive) from %d images", len(rd), int(rd.labels.sum()),
             len(samples))
    # the rectangle images are all the benchmark reads: the whole images (2.5 MB each, 2.2 GB
    # at Cornell's 885) are not held through the hours of the table
    del samples
    run = functools.partial(
        rec.run_recognition_benchmark,
        rd, out, learners=learners or LEARNERS, encoders=encoders or ENCODERS, split=split,
        n_folds=n_folds, inner_folds=inner_folds,
        C_grid=rec.PAPER_C_GRID if paper_grid else rec.C_GRID, n_atoms=n_atoms, whiten=whiten,
        n_patches=n_patches, extra=extra, random_state=seed, progress=progress,
        figure5_sizes=(50, 100, 200, 300, 400) if figure5 else None,
    )
    if executor is None:
        return run(n_jobs=n_jobs)
    with executor.activate():  # the executor's backend and workers (n_jobs=None defers)
        return run(n_jobs=None)


def recognition_choice(path, learner: str, encoder: str):
    """The most often chosen hyper-parameters of one cell of a recognition benchmark.

    For a detection benchmark that takes them from :func:`recognition_benchmark`'s results.

    Parameters
    ----------
    path : str or Path
        Its ``recognition.json``.
    learner, encoder : str
        The cell.

    Returns
    -------
    encoder_param : float or None
    C : float or None

    Raises
    ------
    ValueError
        When the file has no such cell (naming the file).
    """
    summary = read_json(path, "recognition results")
    with file_errors(path, "recognition results"):
        for cell in summary.get("cells", []):
            if cell.get("learner") == learner and cell.get("encoder") == encoder:
                params = Counter(json.dumps(f.get("encoder_param")) for f in cell["folds"])
                Cs = Counter(f.get("C") for f in cell["folds"])
                return json.loads(params.most_common(1)[0][0]), Cs.most_common(1)[0][0]
    raise ValueError(f"{path}: no {learner}-{encoder} cell to take hyper-parameters from")
