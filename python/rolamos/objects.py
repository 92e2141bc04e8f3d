"""Object identification on seafloor maps (``rolamos objects``): bag of visual words / Fisher
vectors and one SVM per class, as in the paper (section 4.5).

- ``train(data, output=None, **options)``: a model from a folder of images per class
  (``background``: negatives only); options as ``rolamos objects train``'s switches;
- ``evaluate(data, model)``: accuracy, per-class precision and recall, the confusion matrix;
- ``detect(store, model, **options)``: sliding windows over the mosaic (or a patch) through the
  tile cache, detections written as GeoJSON into the store and returned;
- ``ObjectModel.load(path).classify(image)``: the classes' scores for one image (NumPy RGB);
- ``validate([train, validation], folds=5, repeats=1, **options)``: repeated stratified
  cross-validation of the options, the figure an unseen split gives (mean and spread).

Box detection of one kind of object (Nephrops burrows) from YOLO-boxed frames:

- ``train_boxes(data, output=None, label="burrow", **options)`` -> ``BoxDetector``;
- ``evaluate_boxes(data, model)``: ``ap50``, ``precision``, ``recall``, ``f1``;
- ``validate_boxes(data, folds=3, **options)``: station-wise cross-validation;
- ``BoxDetector.load(path).detect(image)``: boxes in one image;
- ``detect(store, model)`` takes either kind of model; a box detector also writes the density
  layer (``Store.density()``).
"""
from __future__ import annotations

import json
import os
from typing import Any, Dict, Union

from ._rolamos import (BoxDetector, ObjectModel, is_box_detector, objects_detect, objects_detect_boxes,
                       objects_evaluate, objects_evaluate_boxes, objects_train, objects_train_boxes,
                       objects_validate, objects_validate_boxes)

__all__ = ["BoxDetector", "ObjectModel", "detect", "evaluate", "evaluate_boxes", "train", "train_boxes", "validate",
           "validate_boxes"]


def train(data, output=None, *, progress=None, **options) -> ObjectModel:
    """Trains a model on ``data`` (a folder per class) and saves it to ``output`` (.yml.gz) when
    given. Returns the model."""
    return objects_train(os.fspath(data), None if output is None else os.fspath(output), progress=progress,
                         **options)


def evaluate(data, model: Union[str, "os.PathLike[str]", ObjectModel], *, progress=None) -> Dict[str, Any]:
    """Classifies every image of ``data`` (a folder per class) with ``model`` (a model or its
    file) and compares with the folder labels."""
    return objects_evaluate(os.fspath(data), model if isinstance(model, ObjectModel) else os.fspath(model),
                            progress=progress)


def validate(data, folds: int = 5, repeats: int = 1, *, progress=None, **options) -> Dict[str, Any]:
    """Cross-validates training ``options`` over ``data`` (a folder per class, or a list of such
    folders joined): ``mean`` and ``spread`` of the folds' accuracy, ``fold_accuracy``, pooled
    per-class ``recall`` and ``confusion``."""
    dirs = [os.fspath(d) for d in ([data] if isinstance(data, (str, os.PathLike)) else data)]
    return objects_validate(dirs, folds, repeats, progress=progress, **options)


def train_boxes(data, output=None, *, progress=None, **options) -> BoxDetector:
    """Trains a box detector on ``data`` (``images/`` and ``labels_gt/`` with YOLO boxes) and
    saves it to ``output`` when given."""
    return objects_train_boxes(os.fspath(data), None if output is None else os.fspath(output), progress=progress,
                               **options)


def evaluate_boxes(data, model: Union[str, "os.PathLike[str]", BoxDetector], *, progress=None) -> Dict[str, Any]:
    """AP at IoU 0.5, precision, recall and F1 of ``model`` on boxed frames."""
    return objects_evaluate_boxes(os.fspath(data), model if isinstance(model, BoxDetector) else os.fspath(model),
                                  progress=progress)


def validate_boxes(data, folds: int = 3, *, progress=None, **options) -> Dict[str, Any]:
    """Station-wise cross-validation of box detector ``options`` on boxed frames: pooled and
    per-fold (``folds``) AP50, precision and recall."""
    return objects_validate_boxes(os.fspath(data), folds, progress=progress, **options)


def detect(store, model: Union[str, "os.PathLike[str]", ObjectModel, BoxDetector], *, progress=None,
           **options) -> Dict[str, Any]:
    """Runs ``model`` over the store's mosaic (``patch=N``: a patch) and writes the detections;
    returns the summary with the detections themselves (a GeoJSON FeatureCollection) under
    ``"geojson"``. A box detector (or its file) searches in blocks and also writes the density layer."""
    boxes = isinstance(model, BoxDetector) or (not isinstance(model, ObjectModel) and is_box_detector(os.fspath(model)))
    run = objects_detect_boxes if boxes else objects_detect
    summary = run(os.fspath(store), model if isinstance(model, (ObjectModel, BoxDetector)) else os.fspath(model),
                  progress=progress, **options)
    with open(summary["output"]) as f:
        summary["geojson"] = json.load(f)
    return summary
