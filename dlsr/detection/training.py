"""Training a detector: negatives from the search grid (:func:`sample_grid_negatives`) and hard
negatives (:func:`mine_hard_negatives`), the training data (:func:`detection_training_data`), a
search grid fitted to the positives (:func:`fit_search_grid`) and :func:`train_detector`.

Part of :mod:`dlsr.detection`.
"""

from __future__ import annotations

import dataclasses
import inspect
import logging
import os
import time

import numpy as np

from ..features import rectangle_features
from ..rectangles import array_to_rects
from .grid import PAPER_GRID, SearchGrid, enumerate_candidates, object_region
from .model import SIZE, DLSRDetector, _default_preprocess, _jsonable

log = logging.getLogger(__name__)


def sample_grid_negatives(sample, n: int, rng, grid: SearchGrid = PAPER_GRID,
                          region: str = "auto", background=None,
                          min_height: float = 0.006) -> np.ndarray:
    """Negatives drawn from the detector's own search space.

    The object region is found as the detectors find it (:func:`~dlsr.detection.object_region` with
    ``method=region``), the candidates are those the detectors score
    (:func:`~dlsr.detection.enumerate_candidates` with ``grid``: inside the image, enough of them on
    the dilated region), and ``n`` of the candidates that **fail** the rectangle metric against
    every positive (:func:`dlsr.metrics.rectangle_metric_many`) are drawn uniformly without
    replacement. These include the background, object-edge and small rectangles a detector proposes
    and a recognition training set (labelled rectangles around the grasps) never shows.

    Parameters
    ----------
    sample : GraspSample
    n : int
        Negatives wanted (>= 0).
    rng : numpy.random.Generator or int or None
        Resolved with ``numpy.random.default_rng``.
    grid : SearchGrid
    region : {"auto", "background", "mask", "depth"}
        See :func:`~dlsr.detection.object_region`.
    background : ndarray of shape (H, W, 3) or None
    min_height : float

    Returns
    -------
    ndarray of shape (k, 5)
        ``k = min(n, failing candidates)``; empty when the image has no positive (nothing to
        fail against) or no candidate (empty region). A shortfall is logged.
    """
    from ..metrics import rectangle_metric_many
    from ..rectangles import rects_to_array

    if int(n) != n or n < 0:
        raise ValueError(f"n must be a non-negative integer, got {n}")
    n = int(n)
    if n == 0 or not sample.positives:
        return np.zeros((0, 5))
    rng = np.random.default_rng(rng)
    obs = sample_observation(sample)
    reg, how = object_region(obs, background, region, min_height)
    cand = enumerate_candidates(reg, grid)
    pos = rects_to_array(sample.positives)
    order = rng.permutation(len(cand))
    batch = max(4 * n, 256)
    found, count = [], 0
    for s in range(0, len(order), batch):  # the first n failures of a random order
        c = cand[order[s:s + batch]]
        c = c[~rectangle_metric_many(c, pos)]
        found.append(c)
        count += len(c)
        if count >= n:
            break
    out = np.concatenate(found)[:n] if found else np.zeros((0, 5))
    if len(out) < n:
        log.info("image %s: %d of %d grid negatives (%d candidates, region %s)",
                 sample.image_id, len(out), n, len(cand), how)
    return out


def sample_observation(sample) -> dict:
    """The observation dict a detector reads (``rgb``, ``depth``, ``depth_valid``, and
    ``mask`` and ``K`` when the sample has them) of a :class:`dlsr.datasets.GraspSample`."""
    obs = {"rgb": sample.rgb, "depth": sample.depth, "depth_valid": sample.depth_valid}
    if sample.mask is not None:
        obs["mask"] = sample.mask
    if sample.K is not None:
        obs["K"] = sample.K
    return obs


def mine_hard_negatives(detector, samples, n: int, pool: int = 200) -> list[np.ndarray]:
    """The best-scoring candidates that fail the rectangle metric, per image.

    Hard-negative mining (Dalal and Triggs 2005; Felzenszwalb et al. 2010): the detector runs
    on its own training images and the ``n`` best of its ``pool`` top candidates that fail the
    rectangle metric against every positive become negatives.

    Parameters
    ----------
    detector : ExactGridDetector or DenseDetector
        Its ``top_k`` is raised to ``pool`` for the run (on a copy).
    samples : sequence of GraspSample
        Training images.
    n : int
        Hard negatives per image (>= 1).
    pool : int
        Top candidates looked at per image.

    Returns
    -------
    list of ndarray of shape (k_i, 5)
        One per sample, ``k_i <= n`` (0 for images without positives or candidates).
    """
    import copy

    from ..metrics import rectangle_metric_many
    from ..rectangles import rects_to_array

    if int(n) != n or n < 1:
        raise ValueError(f"n must be a positive integer, got {n}")
    det = copy.copy(detector)
    det.top_k = max(int(pool), int(n))
    out = []
    for s in samples:
        if not s.positives:
            out.append(np.zeros((0, 5)))
            continue
        d = det.detect(sample_observation(s))
        c = d.rects[~rectangle_metric_many(d.rects, rects_to_array(s.positives))] \
            if len(d.rects) else np.zeros((0, 5))
        out.append(np.asarray(c[: int(n)], dtype=float).reshape(-1, 5))
    return out


def detection_training_data(samples, grid_negatives: float = 1.0,
                            grid: SearchGrid = PAPER_GRID, region: str = "auto",
                            negatives_per_image: int | None = None, random_state=0):
    """The training rectangles of a detector: recognition's, plus negatives from the grid.

    Parameters
    ----------
    samples : sequence of GraspSample
    grid_negatives : float
        Per image, ``round(grid_negatives * m)`` negatives from the detector's candidate grid
        (:func:`sample_grid_negatives`), ``m`` the image's labelled rectangles (positives and
        negatives, sampled ones included); 0 gives recognition's training set.
    grid, region :
        The search space the negatives come from (the detector's).
    negatives_per_image : int or None
        See :func:`dlsr.recognition.recognition_data`.
    random_state : int, numpy.random.Generator or None
        The labelled part is drawn exactly as :func:`~dlsr.recognition.recognition_data`
        draws it with this seed; the grid negatives come from an independent stream spawned
        from it.

    Returns
    -------
    RecognitionData
    """
    from ..recognition import recognition_data

    if not (np.isfinite(grid_negatives) and grid_negatives >= 0):
        raise ValueError(f"grid_negatives must be a finite number >= 0, got {grid_negatives}")
    rng = np.random.default_rng(random_state)
    extra = None
    if grid_negatives > 0:
        grid_rng = rng.spawn(1)[0]  # does not advance rng

        def extra(sample, rects):
            k = int(round(grid_negatives * len(rects)))
            return sample_grid_negatives(sample, k, grid_rng, grid, region)

    return recognition_data(samples, negatives_per_image=negatives_per_image, random_state=rng,
                            extra_negatives=extra)


def _check_quantile(q, name: str) -> None:
    if not 0 <= q < 0.5:
        raise ValueError(f"{name} must be in [0, 0.5), got {q}")


def check_training_options(fit_grid=None, hard_negatives=0, hard_rounds=1,
                           physical: bool = False) -> None:
    """Clear errors for the detector training options beyond the paper, before any work.

    ``fit_grid`` is None or a quantile in ``[0, 0.5)`` (:func:`fit_search_grid`);
    ``hard_negatives`` and ``hard_rounds`` are integers >= 0 (:func:`train_detector`), and
    hard negatives are not mined for a model with ``physical`` features.
    """
    if fit_grid is not None:
        _check_quantile(fit_grid, "fit_grid")
    for name, value in (("hard_negatives", hard_negatives), ("hard_rounds", hard_rounds)):
        if int(value) != value or value < 0:
            raise ValueError(f"{name} must be an integer >= 0, got {value}")
    if physical and hard_negatives:
        raise ValueError("physical features and hard_negatives do not go together yet")


def fit_search_grid(positives, grid: SearchGrid = PAPER_GRID,
                    quantile: float = 0.025) -> SearchGrid:
    """The search grid restricted to the sizes of the training positives.

    Openings (jaw sizes) of ``grid`` are kept when they lie in the ``[quantile, 1 - quantile]``
    range of the positives' openings ``w`` (jaw sizes ``h``), widened by half the grid's
    spacing; angles, centres, dilation and coverage are unchanged. The rectangle images are
    scale-normalised (the opening maps to 24 px), so the classifier cannot tell a size it never
    saw labelled; searching only the labelled sizes keeps the search space the training data
    covers (anchor sizes fitted to the training boxes, as object detectors do).

    Parameters
    ----------
    positives : array of shape (n, 5) or list of GraspRectangle
        Training positives (never test ones).
    grid : SearchGrid
    quantile : float
        In ``[0, 0.5)``.

    Returns
    -------
    SearchGrid
        Keeps at least the grid value nearest the median on each axis.

    Raises
    ------
    ValueError
        No positives, a bad quantile, or no (opening, jaw) pair with opening >= jaw left.
    """
    from ..rectangles import as_rect_array

    pos = as_rect_array(positives)
    if len(pos) == 0:
        raise ValueError("fit_search_grid needs at least one positive rectangle")
    _check_quantile(quantile, "quantile")

    def keep(values, x):
        v = np.sort(np.asarray(values, dtype=float))
        half = np.min(np.diff(v)) / 2 if len(v) > 1 else 0.0
        lo, hi = np.quantile(x, quantile), np.quantile(x, 1 - quantile)
        kept = v[(v >= lo - half) & (v <= hi + half)]
        if len(kept) == 0:
            kept = v[[np.argmin(np.abs(v - np.median(x)))]]
        return tuple(float(a) for a in kept)

    fitted = dataclasses.replace(grid, openings=keep(grid.openings, pos[:, 3]),
                                 jaws=keep(grid.jaws, pos[:, 4]))
    if not fitted.pairs():
        raise ValueError(f"fitted grid has no opening >= jaw size (openings {fitted.openings}, "
                         f"jaws {fitted.jaws})")
    return fitted


def train_detector(
    samples,
    learner: str = "NKM",
    encoder: str = "Natural",
    encoder_param=None,
    C: float = 1.0,
    n_atoms: int = 300,
    whiten: bool = True,
    n_patches: int = 100_000,
    negatives_per_image: int | None = None,
    grid_negatives: float = 1.0,
    fit_grid: float | None = None,
    hard_negatives: int = 0,
    hard_rounds: int = 1,
    extra_patches=None,
    physical: bool = False,
    physical_weight: float = 4.0,
    physical_bins: int = 6,
    random_state=0,
    data=None,
    representation=None,
    features=None,
    **config,
) -> DLSRDetector:
    """Train the recognition model on the labelled rectangles of ``samples``.

    Parameters
    ----------
    samples : sequence of GraspSample
        Training images only (fold hygiene is the caller's). Images without negatives
        (Jacquard) get sampled negatives (:func:`dlsr.recognition.recognition_data`).
    learner, encoder, encoder_param :
        See :class:`dlsr.features.DLSRFeatures`; ``encoder_param`` None takes the middle of the
        reference grid (ignored by "Natural").
    C : float
        SVM cost.
    n_atoms, whiten, n_patches :
        Representation settings (:func:`dlsr.features.fit_representation`).
    negatives_per_image : int or None
    grid_negatives : float
        Negatives from the detector's own candidate grid (``config["grid"]`` and
        ``config["region"]``, the defaults otherwise) per labelled rectangle of an image
        (:func:`detection_training_data`): 1 (default) doubles the training set, 0 trains on
        the labelled rectangles only (the recognition model).
    fit_grid : float or None
        The search grid (``config["grid"]``, the paper's by default) is restricted to the
        openings and jaw sizes of the training positives (:func:`fit_search_grid` with this
        quantile, e.g. 0.025) and saved in the model, so detection and the grid negatives use
        it; None (default) keeps the grid as given (the paper's). A departure from the
        paper, off by default.
    hard_negatives : int
        After the first fit, ``hard_rounds`` rounds of hard-negative mining
        (:func:`mine_hard_negatives`): the dense detector (the model's grid and region, no
        exact rescoring) runs on every training image, up to ``hard_negatives`` of its best
        candidates that fail the rectangle metric join the negatives, and the SVM (not the
        representation) is refitted. 0 (default): none, as the paper.
    hard_rounds : int
    extra_patches : tuple (patches, masks), str, Path or None
        Unlabelled patches, each ``(m, 6, 6, 8)``, or a patch file
        (:func:`dlsr.patches.load_patch_file`), joined to dictionary learning and whitening
        only (self-taught learning, the paper's Table 3); the SVM's training rectangles are
        unchanged.
    physical : bool
        Join the rectangles' physical features (:mod:`dlsr.detection.physical`: opening and
        jaw size in metres, heights of the centre and of the finger footprints above the
        table, place on the object's axes) to the DLSR features in the one SVM, as quantile-bin
        indicators (``physical_bins`` per feature) standardised like the rest and then scaled
        by ``physical_weight``. Needs each sample's camera matrix (``sample.K``: graspsim
        datasets record it); the object region is the detectors' (``config["region"]``).
        A departure from the paper, off by default (see the README for the validation that
        chose 6 bins and weight 4).
    physical_weight : float
    physical_bins : int
    random_state : int
    data : RecognitionData or None
        Precomputed training rectangles of ``samples`` (skips preprocessing), e.g. from
        :func:`detection_training_data` with the same ``negatives_per_image``,
        ``grid_negatives`` and (fitted) grid, which are then only recorded in the model's
        config.
    representation : Representation or None
        The representation of ``learner`` already fitted on ``data`` with these
        ``n_atoms``, ``whiten``, ``n_patches``, ``extra_patches`` and ``random_state``
        (skips its fit; :func:`train_detectors` shares one between models of one learner).
    features : ndarray of shape (n, k), float32, or None
        The features of ``data``'s rectangles under ``representation`` and this encoder
        (:func:`dlsr.features.rectangle_features`), already computed; only with ``data`` and
        ``representation`` (:func:`train_detectors` computes every model's in one pass).
    **config :
        Detector options stored in the model (``detector``, ``grid`` (dict), ``top_k``,
        ``rescore``, ``region``).

    Returns
    -------
    DLSRDetector
    """
    from ..features import default_encoder_param, fit_representation
    from ..svm import FeatureStandardizer, SquaredHingeSVC

    encoder_param = default_encoder_param(encoder, encoder_param)
    if features is not None and (data is None or representation is None):
        raise ValueError("features are only given with the data and the representation "
                         "they come from")
    check_training_options(fit_grid, hard_negatives, hard_rounds, physical)
    if physical:
        _check_physical_options(samples, physical_weight, physical_bins)
    extra_patches = _loaded_patches(extra_patches)
    t0 = time.perf_counter()
    sgrid, data = _training_data(samples, config, fit_grid, grid_negatives,
                                 negatives_per_image, random_state, data)
    if representation is None:
        rep = fit_representation(data.images, data.masks, learner, n_atoms=n_atoms,
                                 whiten=whiten, n_patches=n_patches, extra=extra_patches,
                                 random_state=random_state)
    elif representation.learner != learner:
        raise ValueError(f"the representation given is {representation.learner!r}'s, "
                         f"not {learner!r}'s")
    else:
        rep = representation
    polarity = not (learner == "NKM" and encoder == "Natural")
    if features is None:
        F = rectangle_features(data.images, data.masks, rep, encoder, encoder_param,
                               polarity=polarity)
    else:
        F = np.asarray(features)
        if F.shape[0] != len(data.labels):
            raise ValueError(f"features for {F.shape[0]} rectangles, the data has "
                             f"{len(data.labels)}")
    labels = np.asarray(data.labels)
    n_hard = 0
    k = F.shape[1]
    enc = None
    if physical:
        from .physical import PhysicalEncoder

        P = training_physical_features(samples, data, config.get("region", "auto"))
        enc = PhysicalEncoder(int(physical_bins)).fit(P)
        F = np.hstack([F.astype(np.float64), enc.transform(P)])
    scaler = FeatureStandardizer().fit(F)
    Z = scaler.transform(F)
    if physical:
        Z[:, k:] *= physical_weight
    svm = SquaredHingeSVC(C=C).fit(Z, data.labels)
    if hard_negatives:
        from ..preprocess import rectangle_images

        for _ in range(int(hard_rounds)):
            model = DLSRDetector(rep, encoder, encoder_param, polarity, scaler.mean_,
                                 scaler.scale_, np.asarray(svm.coef_[0]),
                                 float(svm.intercept_[0]), preprocess=_default_preprocess())
            det = model.detector("dense", grid=sgrid, region=config.get("region", "auto"),
                                 rescore=0)
            mined = mine_hard_negatives(det, samples, int(hard_negatives))
            ims, mks = [], []
            for smp, rects in zip(samples, mined, strict=True):
                if len(rects):
                    im, mk = rectangle_images(smp.rgb, smp.depth, smp.depth_valid,
                                              array_to_rects(rects), size=SIZE)
                    ims.append(im)
                    mks.append(mk)
            if not ims:
                log.info("hard-negative mining found no failing candidate")
                break
            Fh = rectangle_features(np.concatenate(ims), np.concatenate(mks), rep, encoder,
                                    encoder_param, polarity=polarity)
            F = np.concatenate([F, Fh])
            labels = np.r_[labels, np.zeros(len(Fh), labels.dtype)]
            n_hard += len(Fh)
            scaler = FeatureStandardizer().fit(F)
            svm = SquaredHingeSVC(C=C).fit(scaler.transform(F), labels)
    info = {"learner": learner, "encoder": encoder, "encoder_param": _jsonable(encoder_param),
            "C": float(C), "n_atoms": int(n_atoms), "whiten": bool(whiten),
            "n_patches": int(n_patches), "grid_negatives": float(grid_negatives),
            "fit_grid": None if fit_grid is None else float(fit_grid),
            "hard_negatives": int(hard_negatives), "hard_rounds": int(hard_rounds),
            "n_hard_negatives": int(n_hard),
            "n_extra_patches": 0 if extra_patches is None else int(len(extra_patches[0])),
            "n_train_rectangles": int(len(labels)),
            "n_train_positive": int(np.sum(labels == 1)),
            "train_seconds": time.perf_counter() - t0}
    if physical:
        info.update(physical=True, physical_weight=float(physical_weight),
                    physical_bins=int(physical_bins))
    info.update(config)
    if isinstance(info.get("grid"), SearchGrid):
        info["grid"] = info["grid"].to_dict()
    w = np.asarray(svm.coef_[0], dtype=np.float64)
    mean, scale = np.asarray(scaler.mean_), np.asarray(scaler.scale_)
    intercept = float(svm.intercept_[0])
    edges = w_phys = None
    if physical:  # fold the indicators' standardisation and weight into their coefficients
        w_phys = physical_weight * w[k:] / scale[k:]
        intercept -= float(w_phys @ mean[k:])
        edges = tuple(enc.edges_)
    return DLSRDetector(rep, encoder, encoder_param, polarity, mean[:k], scale[:k], w[:k],
                        intercept, preprocess=_default_preprocess(), config=info,
                        physical_edges=edges, physical_coef=w_phys)


def _loaded_patches(extra):
    """``extra_patches`` loaded when given as a patch file's path (as it is otherwise)."""
    if isinstance(extra, (str, os.PathLike)):
        from ..patches import load_patch_file

        return load_patch_file(extra)
    return extra


def _training_data(samples, config: dict, fit_grid, grid_negatives, negatives_per_image,
                   random_state, data=None):
    """The search grid (:func:`_training_grid`) and the training rectangles
    (:func:`detection_training_data`, unless ``data`` is given), which must hold both
    classes."""
    sgrid = _training_grid(samples, config, fit_grid)
    if data is None:
        data = detection_training_data(samples, grid_negatives, sgrid,
                                       config.get("region", "auto"),
                                       negatives_per_image=negatives_per_image,
                                       random_state=random_state)
    if len(np.unique(data.labels)) < 2:
        raise ValueError("training needs positive and negative rectangles")
    return sgrid, data


def _training_grid(samples, config: dict, fit_grid) -> SearchGrid:
    """The search grid of a training (``config["grid"]``, the paper's by default), fitted to
    the positives of ``samples`` with ``fit_grid`` (then also put in ``config``)."""
    sgrid = config.get("grid", PAPER_GRID)
    if isinstance(sgrid, dict):
        sgrid = SearchGrid.from_dict(sgrid)
    if fit_grid is not None:
        from ..rectangles import rects_to_array

        pos = [rects_to_array(s.positives) for s in samples]
        sgrid = fit_search_grid(np.concatenate(pos) if pos else np.zeros((0, 5)), sgrid,
                                fit_grid)
        config["grid"] = sgrid
    return sgrid


def train_detectors(samples, models, random_state=0, **options) -> list[DLSRDetector]:
    """Several detectors trained on the same images, the work they share done once.

    Each model is :func:`train_detector` ``(samples, **model, **options,
    random_state=random_state)``, bit for bit; the training rectangles (the labelled ones and
    the grid negatives, :func:`detection_training_data`) do not depend on the learner or the
    encoder and are made once, and one representation is fitted per learner (the models of
    one learner, e.g. NKM-Natural and NKM-SC, read the same dictionary).

    Parameters
    ----------
    samples : sequence of GraspSample
        Training images only.
    models : sequence of dict
        Per model, its ``learner``, ``encoder`` and optionally ``encoder_param`` and ``C``.
    random_state : int
    **options
        Every other keyword argument of :func:`train_detector`, the same for all models
        (``n_atoms``, ``grid_negatives``, ``fit_grid``, ``extra_patches``, ``region``...).

    Returns
    -------
    list of DLSRDetector
        In the order of ``models``. Each model's ``config["train_seconds"]`` counts the shared
        training rectangles and representation in full (what it takes alone) and its even
        share of the features' pass (every model's features are computed in one pass, the
        patches whitened once: :func:`dlsr.features.rectangle_features_many`);
        ``config["shared_train_seconds"]`` says how much of it was shared and
        ``config["training_data_seconds"]`` how much of that the training rectangles took.
    """
    from ..features import (
        LEARNERS,
        default_encoder_param,
        fit_representation,
        rectangle_features_many,
    )

    own = {"learner", "encoder", "encoder_param", "C"}
    for m in models:
        if not {"learner", "encoder"} <= m.keys() or not m.keys() <= own:
            raise ValueError(f"each model needs 'learner' and 'encoder' (and optionally "
                             f"'encoder_param', 'C'), got {sorted(m)}")
        default_encoder_param(m["encoder"])  # an unknown encoder is refused here
        if m["learner"] not in LEARNERS:
            raise ValueError(f"unknown learner {m['learner']!r}; choose from {LEARNERS}")
    if own & options.keys() or "data" in options or "representation" in options:
        raise ValueError("learner, encoder, encoder_param, C, data and representation are "
                         "per model or shared here, not options")
    options = dict(options)
    if "extra_patches" in options:
        options["extra_patches"] = _loaded_patches(options["extra_patches"])
    defaults = inspect.signature(train_detector).parameters

    def opt(name):  # an option given, else train_detector's default
        return options.get(name, defaults[name].default)

    t0 = time.perf_counter()
    config = {k: v for k, v in options.items() if k in ("grid", "region")}
    _, data = _training_data(samples, config, opt("fit_grid"), opt("grid_negatives"),
                             opt("negatives_per_image"), random_state)
    shared = {"data": time.perf_counter() - t0}
    reps = {}
    for learner in dict.fromkeys(m["learner"] for m in models):
        t1 = time.perf_counter()
        reps[learner] = fit_representation(
            data.images, data.masks, learner, n_atoms=opt("n_atoms"), whiten=opt("whiten"),
            n_patches=opt("n_patches"), extra=opt("extra_patches"), random_state=random_state)
        shared[learner] = time.perf_counter() - t1
    # every model's features in one pass: the patches whitened once for the models that
    # whiten alike (all of them here: one training set, one seed)
    t1 = time.perf_counter()
    features = rectangle_features_many(data.images, data.masks, [
        (reps[m["learner"]], m["encoder"], default_encoder_param(m["encoder"],
                                                                  m.get("encoder_param")),
         not (m["learner"] == "NKM" and m["encoder"] == "Natural")) for m in models])
    shared["features"] = (time.perf_counter() - t1) / len(models)
    out = []
    for m, F in zip(models, features, strict=True):
        model = train_detector(samples, **m, **options, random_state=random_state, data=data,
                               representation=reps[m["learner"]], features=F)
        extra_s = shared["data"] + shared[m["learner"]] + shared["features"]
        model.config["train_seconds"] += extra_s
        model.config["shared_train_seconds"] = extra_s
        model.config["training_data_seconds"] = shared["data"]
        out.append(model)
    return out


def _check_physical_options(samples, weight, bins) -> None:
    if not (np.isfinite(weight) and weight > 0):
        raise ValueError(f"physical_weight must be a finite number > 0, got {weight}")
    if int(bins) < 2:
        raise ValueError(f"physical_bins must be >= 2, got {bins}")
    for s in samples:
        if s.K is None:
            raise ValueError(f"physical features need each image's camera matrix: image "
                             f"{s.image_id} ({s.source}) has none (graspsim datasets record "
                             "it in pcdXXXXcamera.json)")


def training_physical_features(samples, data, region: str = "auto") -> np.ndarray:
    """:func:`dlsr.detection.physical.physical_features` of every training rectangle of
    ``data`` (a :class:`dlsr.recognition.RecognitionData` with ``rects``), measured in its
    image of ``samples``, shape ``(len(data), 9)``."""
    from .grid import object_region, table_surface
    from .physical import PHYSICAL_FEATURES, physical_features

    if data.rects is None:
        raise ValueError("the training data does not record its rectangles (data.rects)")
    by_id = {s.image_id: s for s in samples}
    out = np.zeros((len(data), len(PHYSICAL_FEATURES)))
    ids = np.asarray(data.image_ids)
    for image_id in dict.fromkeys(ids.tolist()):
        s = by_id[image_id]
        rows = np.flatnonzero(ids == image_id)
        obs = sample_observation(s)
        reg, _ = object_region(obs, method=region)
        table = table_surface(s.depth, s.depth_valid)
        out[rows] = physical_features(obs, data.rects[rows], reg, table)
    return out

