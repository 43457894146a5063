"""Camera matrices of real datasets: fitted where the data has them, estimated where it has not.

* **Cornell** records a PCD point cloud per image (``pcdXXXX.txt``): each point's ``x y z``
  (millimetres) and the pixel it belongs to (``index = row * 640 + col``). The points need not
  be in the camera's optical frame: real Cornell clouds are forward-left-up and tilted with
  the camera (a row of ``pcd0100.txt`` reads ``1924.064 -647.111 -119.4176 0 25547``: x the
  distance forward, y to the left, z up). :func:`fit_camera` fits the whole pinhole camera,
  intrinsics and pose, to the point/pixel pairs (a rotation about the cloud's origin, else a
  general 3 x 4 projection; exact up to the pixel quantisation of the index, about 0.3 px).
  The matrix, the cloud's pose ``T_cam_cloud`` and the residual are cached beside the images
  as ``pcdXXXXcamera.json`` (the file :func:`dlsr.datasets.load_cornell` and ``graspsim
  detect`` read). A cloud that fits no pinhole camera gets a warning naming it and the
  estimate below; the image still loads. A Cornell image without its point cloud (only the
  preprocessed ``pcdXXXXd.tiff``) gets :data:`CORNELL_FALLBACK_K`, an estimate (below).
* **Depth.** The pipeline's depth is the depth along the optical axis, ``z``, as the
  simulator renders it and as ``K`` back-projects it (``X = z K^-1 [u v 1]``). The common
  Cornell preprocessing writes the *range*, the norm of each point, into ``pcdXXXXd.tiff``:
  up to 21 % more than ``z`` at the corners of a 640 x 480 image at 585 px. So a Cornell
  cloud's depth is its points' ``z`` in the fitted camera frame, and a TIFF beside a cloud or
  its fitted camera is converted
  (:func:`range_to_depth`). A TIFF alone, without a camera, is used as read (``K`` unknown):
  give the point cloud or a camera file when the metric features matter. graspsim's own
  datasets write ``z`` (their camera files carry ``T_world_cam``).
* **Jacquard** ships no intrinsics. Its grasp files measure the jaw size in pixels, and the
  Jacquard paper's simulated gripper has jaws of 1, 2, 3, 4 and 6 cm (Depierre, Dellandrea and
  Chen, "Jacquard: A Large Scale Dataset for Robotic Grasp Detection", IROS 2018): a jaw of
  ``h`` px at depth ``z`` m is ``h z / f`` m, so ``h z`` clusters at ``f`` times those sizes.
  On the 28 sample views the clusters sit at 1 : 2 : 3 : 4 : 6 (the paper's sizes, up to the
  unit) and give ``f`` = :data:`JACQUARD_FOCAL_PX` px for the 1024 x 1024 renders
  (:func:`focal_from_jaw_sizes`), with the principal point assumed at the image centre.

How far off the estimates can be
--------------------------------
* Jacquard: the views' own estimates lie within 1.2 % of the pooled one (1879 to 1911 px;
  tested within 2 %), the spread inside a cluster (the jaw measured at the grasp centre's
  depth, not at the jaws) is about 2 %; a principal point a few pixels off the centre moves
  an off-centre grasp's metric opening by well under 1 %. So openings in metres are within
  about 3 % (if the paper's sizes are right: they are what makes the clusters 1:2:3:4:6).
* Cornell without a point cloud: the Kinect v1 depth camera's focal length is about 585 px at
  640 x 480 (the value PCL's KinectFusion maintainers measured against the 525 px of the
  colour camera, PointCloudLibrary/pcl pull request 389); devices differ by a few per cent and
  a registered cloud may use the colour camera's 525 px, so openings from it can be off by up
  to about 10 %. Give the point cloud (or ``--intrinsics``) when it matters.
"""

from __future__ import annotations

from .cornell import (
    CORNELL_FALLBACK_K,
    CornellCamera,
    cornell_camera,
    cornell_camera_matrix,
    pcd_camera_matrix,
    pcd_points_and_pixels,
    range_to_depth,
    read_pcd_points,
)
from .fit import MAX_FIT_RMS_PX, CameraFit, fit_camera, fit_camera_matrix
from .jacquard import (
    JACQUARD_FOCAL_PX,
    JACQUARD_JAW_SIZES_M,
    focal_from_jaw_sizes,
    jacquard_camera_matrix,
)
from .matrix import (
    camera_matrix,
    check_camera_matrix,
    read_camera_file,
    read_camera_matrix,
    write_camera_file,
)

__all__ = [
    "CORNELL_FALLBACK_K",
    "JACQUARD_FOCAL_PX",
    "JACQUARD_JAW_SIZES_M",
    "MAX_FIT_RMS_PX",
    "CameraFit",
    "CornellCamera",
    "camera_matrix",
    "check_camera_matrix",
    "read_camera_file",
    "read_camera_matrix",
    "fit_camera",
    "fit_camera_matrix",
    "focal_from_jaw_sizes",
    "jacquard_camera_matrix",
    "read_pcd_points",
    "pcd_camera_matrix",
    "pcd_points_and_pixels",
    "cornell_camera",
    "cornell_camera_matrix",
    "range_to_depth",
    "write_camera_file",
]
