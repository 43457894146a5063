"""What a run's settings imply for its stages: the detectors of the trial stage.

Below both :mod:`graspsim.pipeline`, which runs the stages, and :mod:`graspsim.pipeline.report`,
which
writes them up, so the two agree on the names without importing each other. The functions read
only the settings they name, from a :class:`graspsim.pipeline.RunConfig` or anything with the
same attributes.
"""

from __future__ import annotations

__all__ = ["departs_from_paper", "trial_names"]


def departs_from_paper(config) -> bool:
    """Whether DLSR's trial configuration is not the paper's (then ``dlsr-paper`` runs).

    Parameters
    ----------
    config : RunConfig
        Its ``gripper_aware``, ``physical`` and ``detector`` settings are read.

    Returns
    -------
    bool
    """
    return bool(config.gripper_aware or config.physical or config.detector == "lattice")


def trial_names(config) -> list[str]:
    """The detectors of the trial stage, DLSR first.

    Parameters
    ----------
    config : RunConfig
        Its ``baselines`` and the settings :func:`departs_from_paper` reads.

    Returns
    -------
    list of str
        ``dlsr``, ``dlsr-paper`` (the paper's configuration, when :func:`departs_from_paper`),
        then the baselines.
    """
    return ["dlsr", *(["dlsr-paper"] if departs_from_paper(config) else []),
            *config.baselines]
