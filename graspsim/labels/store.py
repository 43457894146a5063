"""Physics labels of trial scenes, kept once and shared by every detector tried on them.

Trial ``i`` of a campaign (seed, objects, :class:`graspsim.eval.trials.TrialConfig`, execution
parameters) is the same scene, seen the same way, for every detector, and its labelling
candidates come from the trial's own stream: which of them the physics grasps, and their
ranking, do not depend on the detector. Labelling is most of a trial's simulation (32
candidates executed: about 60 % of a mask-pca trial's time, against 5 % for the grasp itself),
so runs that try several detectors on the same scenes (``graspsim run``'s five, a data-efficiency
curve's rows) label each scene once through a :class:`SceneLabels` folder and the others read
it. The trials' records are the same as without it.

A folder holds ``key.json`` (the campaign's configuration without the detector; a folder of
other scenes is refused) and ``labels.jsonl``, one entry per scene, appended and flushed as
each is labelled:

* ``index``: the trial;
* ``positives``: the indices of the candidates the physics grasped, best first
  (:func:`graspsim.labels.labelling.rank_order`);
* ``n_labelled``: candidates executed;
* ``candidates``: a digest of the candidates (:func:`candidates_digest`). The candidates are
  drawn again from the trial's stream when an entry is used; an entry whose digest differs
  (the sampling changed since it was written) is not used: the scene is labelled again and the
  new entry, appended, replaces it.
"""

from __future__ import annotations

import hashlib
import json
import logging
from pathlib import Path

import numpy as np

from dlsr.records import read_json, read_jsonl, write_json_atomic

log = logging.getLogger(__name__)

__all__ = ["SceneLabels", "candidates_digest"]


def candidates_digest(candidates) -> str:
    """A short digest of labelling candidates (their ``x, y, theta, w, h`` as float64).

    Parameters
    ----------
    candidates : list of GraspRectangle

    Returns
    -------
    str
        16 hexadecimal digits.
    """
    arr = np.array([r.as_array() for r in candidates], dtype=np.float64).reshape(-1, 5)
    return hashlib.sha256(arr.tobytes()).hexdigest()[:16]


class SceneLabels:
    """A folder of trial scenes' physics labels (see the module docstring).

    Parameters
    ----------
    folder : str or Path
        Made by :meth:`open` when missing.
    """

    def __init__(self, folder):
        self.folder = folder

    @property
    def _jsonl(self) -> Path:
        return Path(self.folder) / "labels.jsonl"

    @classmethod
    def open(cls, folder, key: dict) -> SceneLabels:
        """The store in ``folder`` for the scenes of ``key``, made when missing.

        Raises
        ------
        ValueError
            When ``folder`` holds the labels of other scenes (another seed, objects, trial or
            execution configuration): the message names its ``key.json``.
        """
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / "key.json"
        key = json.loads(json.dumps(key))
        if path.exists():
            if read_json(path, "scene labels key") != key:
                raise ValueError(f"{folder} holds the labels of other scenes ({path}): give "
                                 "another folder for these trials")
        else:
            write_json_atomic(path, key)
        return cls(folder)

    def read(self) -> dict[int, dict]:
        """The entries by trial index (the last one of an index: a relabelled scene)."""
        out: dict[int, dict] = {}
        for e in read_jsonl(self._jsonl, required=("index", "positives", "n_labelled",
                                                   "candidates"), repair=True):
            out[int(e["index"])] = e
        return out

    def add(self, entry: dict) -> None:
        """Append one scene's entry (one line, flushed)."""
        with open(self._jsonl, "a") as fh:
            fh.write(json.dumps(entry) + "\n")
            fh.flush()


def known_positives(entry: dict | None, candidates) -> list | None:
    """The ranked positives ``entry`` gives for ``candidates`` (drawn again from the trial's
    stream), or None when there is no entry or it was made from other candidates."""
    if entry is None:
        return None
    if entry["candidates"] != candidates_digest(candidates):
        log.info("scene labels of trial %s were made from other candidates: labelling again",
                 entry["index"])
        return None
    return [candidates[int(i)] for i in entry["positives"]]
