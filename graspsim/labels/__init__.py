"""Physics labels: candidate grasps executed to label a scene, which objects a hand can grasp
at all, and the store of a scene's labels shared by the detectors tried on it."""
