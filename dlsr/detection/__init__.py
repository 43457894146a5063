"""Grasp detection: find the best rectangle in a whole image (the paper's Table 2).

The search is Lenz et al.'s, as the authors' configuration mirrors
(``shared/reference/dlsr-reference-facts.md``): the object region is found, dilated by 20 px,
and candidates are laid out in its bounding box, centres every 10 px, closing angles
0, 15, ..., 165 degrees, openings and jaw sizes 10, 20, ..., 90 px with opening >= jaw size
(45 pairs x 12 angles per centre). A candidate is kept when at least 50 % of its area lies on
the (dilated) object region and all four corners lie inside the image. Each candidate is scored
by the SVM decision function of the recognition model; the best score is the detection.

Two detectors share the candidates and the trained model (:class:`DLSRDetector`):

* :class:`ExactGridDetector` featurises every candidate exactly as recognition does
  (:func:`dlsr.preprocess.rectangle_images` then :func:`dlsr.features.rectangle_features`,
  batched) and scores it. Several minutes per image, like the paper.
* :class:`DenseDetector` computes the same scores densely. The SVM is linear and pooling is a
  sum, so with the feature standardisation folded in, a candidate's score is
  ``const + sum_q sum_{patches p in quadrant q} v_q . code(p)``: four per-pixel score maps
  (``v_q . code``) and four box sums. Per angle the whole 8-channel image is rotated once (the
  normals recomputed on the rotated full-resolution canvas), per opening ``w`` the canvas is
  rescaled once by ``24 / w`` (so the opening maps to 24 px, as the crop's longer side does), every
  6x6 patch some candidate needs is standardised, whitened and encoded once, the four score maps
  get summed-area tables, and every candidate is scored with a handful of table look-ups. The
  top ``rescore`` candidates are then rescored exactly (recognition's rectangle images, encoded
  by the same kernels: :meth:`DenseDetector.exact_scores`) and re-ranked.

  The encoding is compute-bound and organised for it (:class:`_PatchScorer`,
  :mod:`dlsr._dense`): per-patch group statistics from running window sums, standardised patches
  gathered by a compiled kernel, whitening and the k-means centroid products of NKM-Natural
  folded into one float32 matrix (``P C^T``), the whitened norm from the triangular Cholesky
  factor of ``P P^T`` (about 2 x 288 x 480 operations per patch instead of 2 x 288 x 588), the
  triangle codes and their quadrant weights fused in one compiled pass; a patch with no valid
  depth (common in clutter: a pile's shadows) whitened on its 144 colour entries only
  (2 x 144 x 344 operations instead of 2 x 288 x 488 for a masked patch). The (angle, opening)
  canvases run in ``n_threads`` threads, longest first, each with single-threaded BLAS.

Where dense and exact differ
----------------------------
For a candidate whose crop lines up with the canvas grid (angle a multiple of 90 degrees, crop
origin on the resized canvas's grid) with ``h == w`` (no padding), no depth outlier in the crop
and a depth map whose normals do not depend on the crop border (e.g. a plane), the two scores are
equal up to float rounding (tested). Otherwise the dense score is an approximation:

* **padding** (``h < w``): the exact crop is padded above and below the ``h`` rows; patches
  entirely in the padding get the code of an all-masked patch (exact), but patches straddling
  the padding edge are taken from the canvas, which has image content there;
* **sub-pixel position**: the candidate's window rarely falls on the canvas grid; its score is
  the bilinear interpolation of the window scores at the four neighbouring grid positions;
* **per-crop depth processing**: the exact crop masks depth outliers (4 sigma of the crop,
  twice), fills holes within the crop and extrapolates normals at the crop border; the canvas
  does none of the first, fills holes once over the image (before rotation) and has real
  neighbours at the border. (The crop's mean depth is subtracted in the exact path and not in
  the canvas; per-patch standardisation removes it either way.)

``scripts/bench_detection.py`` measures the differences (score error for ``h == w`` and
``h < w``, top-1 agreement by the rectangle metric).

Object region
-------------
:func:`object_region`, in this order: background subtraction when a background image is given
(the sum over R, G, B of ``|image - background|`` above 100, largest 8-connected blob; Cornell);
the observation's ``mask`` when it has one (Jacquard, simulation); otherwise the object standing
on the table, from depth alone (:func:`table_plane_mask`): the table's surface is found by RANSAC
on the dominant plane in inverse depth (for a pinhole camera ``1/z`` of a plane is linear in the
pixel coordinates) with a loose band, then refitted robustly with polynomials up to degree 3 in
inverse depth (Cornell's depth is the distance to the camera, whose table is curved in ``1/z``
by up to 5 cm), inlier bands at 3 robust standard deviations of the table's depth noise; the
object is the blob standing more than 6 mm (or 3 sigma) in front of it, inside the table's
convex hull, that the table encloses (walls, boards and the floor beyond the edge are not).

Departures and choices (named options)
--------------------------------------
* ``SearchGrid.coverage_on="dilated"``: the 50 % is measured on the dilated region (Lenz's
  search); ``"object"`` uses the undilated region.
* Candidate centres are the multiples of ``step`` inside the dilated region's bounding box.
* Coverage is counted on pixel centres in the rotated frame (summed-area table per angle).
* The dense path fills depth holes once over the image before rotating (the exact path fills
  each rotated crop), by default with the nearest valid depth (``DenseDetector(fill=...)``).
* ``SearchGrid.clear_jaws`` (off by default): only candidates centred on the object whose jaws
  come down beside it (:func:`jaws_clear`); with the training option ``fit_grid`` it is what
  makes small models pick a grasp across a real remote control's short side (``graspsim
  detect`` on Cornell images, tested), where the paper's search picked 10 to 20 px squares on
  its edge.
* ``SearchGrid.max_width`` (None by default): only candidates whose opening, measured in metres
  at the depth under their centre with the observation's camera matrix ``K``
  (:func:`opening_widths`), a gripper reaches. ``graspsim`` sets it with ``clear_jaws`` in its
  gripper-aware search (:func:`graspsim.detectors.gripper_aware`) at detection time; the models
  it trains do not carry it.
* Physical features in the SVM (``train_detector(physical=True)``, off by default;
  :mod:`dlsr.detection.physical`): the rectangle's opening and jaw size in metres, the heights
  of its centre and of the two finger footprints above the table, and its place on the object
  region's principal axes, as quantile-bin indicators beside the DLSR features. Every detector
  adds the model's physical term (:meth:`DLSRDetector.physical_scores`) to the DLSR score.
* :class:`LatticeDetector` (``model.detector("lattice")``): instead of the grid, rectangles fitted
  to the object region (lattice points every 15 degrees, openings from the region's chords, the
  physics labeller's candidates of :mod:`graspsim.labelling`), at most 192 of them scored
  exactly.

Modules
-------
* :mod:`dlsr.detection.grid`: :class:`SearchGrid`, the object region, :func:`enumerate_candidates`;
* :mod:`dlsr.detection.table`: the table fitted to the depth, the object standing on it;
* :mod:`dlsr.detection.model`: :class:`DLSRDetector` and its files;
* :mod:`dlsr.detection.training`: negatives, training data, :func:`fit_search_grid`,
  :func:`train_detector`, :func:`train_detectors` (several models, the shared work once);
* :mod:`dlsr.detection.exact`: :class:`Detection`, :class:`ExactGridDetector`;
* :mod:`dlsr.detection.dense`: :class:`DenseDetector`;
* :mod:`dlsr.detection.lattice`: :func:`lattice_candidates`, :class:`LatticeDetector`,
  :func:`detect_many` (several models on one observation, the shared work done once);
* :mod:`dlsr.detection.physical`: :func:`physical_features`, :class:`PhysicalEncoder`;
* :mod:`dlsr.detection.files`: :func:`detect_files` (``graspsim detect``).

Every public name is importable from ``dlsr.detection``; private helpers stay in their modules.
"""

from .dense import DenseDetector
from .exact import Detection, ExactGridDetector
from .files import detect_files
from .grid import (
    COARSE_GRID,
    PAPER_GRID,
    SearchGrid,
    background_mask,
    complete_region,
    enumerate_candidates,
    fill_unseen_surface,
    jaws_clear,
    object_region,
    opening_widths,
    table_plane_mask,
    table_surface,
    valid_depth,
    within_reach,
)
from .lattice import LatticeDetector, detect_many, lattice_candidates, max_width_px
from .model import (
    DETECTOR_KINDS,
    FORMAT_VERSION,
    GRID,
    PATCH,
    PATCHES_PER_RECTANGLE,
    SIZE,
    SPLIT,
    DLSRDetector,
)
from .physical import PHYSICAL_FEATURES, PhysicalEncoder, physical_features
from .training import (
    check_training_options,
    detection_training_data,
    fit_search_grid,
    mine_hard_negatives,
    sample_grid_negatives,
    sample_observation,
    train_detector,
    train_detectors,
)

__all__ = [
    "DETECTOR_KINDS",
    "LatticeDetector",
    "detect_many",
    "lattice_candidates",
    "max_width_px",
    "PHYSICAL_FEATURES",
    "PhysicalEncoder",
    "physical_features",
    "SearchGrid",
    "PAPER_GRID",
    "COARSE_GRID",
    "Detection",
    "DLSRDetector",
    "ExactGridDetector",
    "DenseDetector",
    "train_detector",
    "train_detectors",
    "detection_training_data",
    "sample_grid_negatives",
    "fit_search_grid",
    "sample_observation",
    "mine_hard_negatives",
    "check_training_options",
    "object_region",
    "complete_region",
    "fill_unseen_surface",
    "opening_widths",
    "table_plane_mask",
    "table_surface",
    "within_reach",
    "background_mask",
    "enumerate_candidates",
    "jaws_clear",
    "PATCHES_PER_RECTANGLE",
    "PATCH",
    "SIZE",
    "SPLIT",
    "GRID",
    "FORMAT_VERSION",
    "valid_depth",
    "detect_files",
]
