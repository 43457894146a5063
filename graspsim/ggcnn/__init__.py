"""Old home of the CNN peers, now :mod:`graspsim.detectors.ggcnn` (networks, maps, training,
the detectors), :mod:`graspsim.eval.offline.ggcnn` (the offline benchmark) and
:mod:`graspsim.eval.data_efficiency` (the learning curve).

Kept only for :mod:`graspsim.ggcnn.detector`, the target of the ``ggcnn`` detector entry point
that installs made before the move recorded (an editable install keeps its entry points until
it is reinstalled) and of code written against it. Import from the new places.
"""
