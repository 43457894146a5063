"""``graspsim run``: the end-to-end job (:mod:`graspsim.pipeline.job`), its configuration
(:mod:`graspsim.pipeline.config`), the trial stage's plan (:mod:`graspsim.pipeline.plan`) and
the report (:mod:`graspsim.pipeline.report`).

The public names of the job and of its configuration are importable from here too
(``graspsim.pipeline.RunConfig``, ``graspsim.pipeline.run_job``), as they were from the module
``graspsim.pipeline`` before the package existed.
"""

from .config import QUICK, RunConfig, load_config
from .job import (
    objectwise_validation,
    resume_job,
    run_folder,
    run_job,
    trial_detector,
)

__all__ = ["RunConfig", "load_config", "run_folder", "run_job", "resume_job",
           "objectwise_validation", "trial_detector", "QUICK"]
