"""Object identification on seafloor maps (``rolamos objects``): bag of visual words / Fisher
vectors and one SVM per class, as in the paper (section 4.5).

- ``train(data, output=None, **options)``: a model from a folder of images per class
  (``background``: negatives only); options as ``rolamos objects train``'s switches;
- ``evaluate(data, model)``: accuracy, per-class precision and recall, the confusion matrix;
- ``detect(store, model, **options)``: sliding windows over the mosaic (or a patch) through the
  tile cache, detections written as GeoJSON into the store and returned;
- ``ObjectModel.load(path).classify(image)``: the classes' scores for one image (NumPy RGB).
"""
from __future__ import annotations

import json
import os
from typing import Any, Dict, Union

from ._rolamos import ObjectModel, objects_detect, objects_evaluate, objects_train

__all__ = ["ObjectModel", "detect", "evaluate", "train"]


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


def detect(store, model: Union[str, "os.PathLike[str]", ObjectModel], *, progress=None, **options) -> Dict[str, Any]:
    """Runs ``model`` over the store's mosaic (``patch=N``: a patch) and writes the detections;
    returns the summary with the detections themselves (a GeoJSON FeatureCollection) under
    ``"geojson"``."""
    summary = objects_detect(os.fspath(store), model if isinstance(model, ObjectModel) else os.fspath(model),
                             progress=progress, **options)
    with open(summary["output"]) as f:
        summary["geojson"] = json.load(f)
    return summary
