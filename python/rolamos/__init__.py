"""rolamos: seafloor maps from a downward-looking underwater camera.

Python bindings of the rolamos library (the same code the ``rolamos`` command calls; docs/python.md):

- ``Store(path)``: a map store: its patches, frames and their placements, the global record,
  its georeference (``pixel_to_map`` / ``map_to_pixel``) and object detections (GeoJSON);
- ``open_image(path_or_store, name="mosaic")``: any part of a mosaic or patch as NumPy arrays
  (RGB(A), uint8 or uint16), read through the bounded tile cache;
- ``Mosaicker(store, **options)``: the online engine, fed frame by frame;
- every step of the command: ``synth``, ``mosaic``, ``compose``, ``align``, ``merge``,
  ``export``, ``convert``, and ``rolamos.objects`` (``train``, ``evaluate``, ``detect``).

Options are keyword arguments named as the command's switches (``--patch-megapixels`` is
``patch_megapixels``), with its defaults; a bad one raises ``ValueError`` naming it. Library
failures raise ``rolamos.Error`` with the library's message (the file and the reason). Long calls
release the GIL, take ``progress=callable(fraction, message)`` and stop on Ctrl-C
(``KeyboardInterrupt``).
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from ._rolamos import Error, Image, Mosaicker, align, compose, convert, describe_image, describe_store, merge
from ._rolamos import export as _export
from ._rolamos import mosaic, synth
from . import objects

__all__ = ["Error", "Frame", "GlobalRecord", "Image", "Mosaicker", "Patch", "Store", "align", "compose", "convert",
           "export", "merge", "mosaic", "objects", "open_image", "synth"]

PathLike = Union[str, "os.PathLike[str]"]


def export(image: Union[PathLike, Image], output: PathLike, *, region: Optional[Sequence[float]] = None,
           level: int = -1, scale: float = 1.0, jpeg_quality: int = 92, progress=None, **options) -> dict:
    """A region (x, y, w, h in level-0 pixels; None: all) of an image (a path or an Image from
    open_image) at full resolution, a level or a scale, to .tif (streamed, pyramidal, keeps the
    georeference), .png or .jpg. Codec options for .tif: compression, quality, tile, ..."""
    path = image.path if isinstance(image, Image) else os.fspath(image)
    return _export(path, os.fspath(output), region=None if region is None else [float(v) for v in region],
                   level=level, scale=scale, jpeg_quality=jpeg_quality, progress=progress, **options)


def _matrix(values) -> Optional[np.ndarray]:
    return None if values is None else np.asarray(values, dtype=float).reshape(3, 3)


@dataclass(frozen=True)
class Patch:
    """One patch of a store, as its manifest and sidecar describe it."""

    id: int
    width: int
    height: int
    n_images: int
    rejected: int
    levels: int
    closed_by: str
    image: str  # the patch image's path
    sidecar: str  # its sidecar's path
    linked: bool
    problem: Optional[str] = None  # set when the patch cannot be read


@dataclass(frozen=True)
class Frame:
    """A frame the engine placed: where it lies in its patch and, once composed, in the mosaic."""

    patch: int
    index: int  # in the input sequence
    source: str
    keyframe: bool  # adjusted with its patch's keyframes (False: placed between keyframes only)
    frame_to_patch: np.ndarray  # 3 x 3 homography, frame pixels -> patch pixels
    frame_to_mosaic: Optional[np.ndarray]  # frame pixels -> mosaic.tif level-0 pixels, once composed
    aligned: bool  # placed by `align` (frame_to_mosaic from its own adjusted placement)
    inliers: int
    registered_by: Optional[str]  # how the engine placed it when not from the frame before
    blended: bool = True  # its pixels are blended into the patch image (keyframes only; the others link)

    def centre(self, in_mosaic: bool = True, frame_size: Tuple[int, int] = None) -> Optional[Tuple[float, float]]:
        """The frame's centre in the mosaic (or its patch), given the frame size (w, h)."""
        H = self.frame_to_mosaic if in_mosaic else self.frame_to_patch
        if H is None or frame_size is None:
            return None
        p = H @ np.array([frame_size[0] / 2, frame_size[1] / 2, 1.0])
        return float(p[0] / p[2]), float(p[1] / p[2])


@dataclass(frozen=True)
class GlobalRecord:
    """The global mosaic's record: size, scale, and its georeference when it has one."""

    width: int
    height: int
    n_images: int
    n_patches: int
    scale: float
    crs: Optional[str]
    geotransform: Optional[Tuple[float, float, float, float, float, float]]


class Store:
    """A rolamos map store (a directory, format in docs/store-format.md)."""

    def __init__(self, path: PathLike):
        self.path = os.fspath(path)
        if not os.path.isdir(self.path):
            raise Error(f"{self.path}: no such store (a directory made by rolamos mosaic)")
        self._info = describe_store(self.path)

    def info(self) -> dict:
        """What ``rolamos info --json`` prints for the store (re-read from disk)."""
        self._info = describe_store(self.path)
        return self._info

    @property
    def patches(self) -> List[Patch]:
        out = []
        for p in self._info["patches"]:
            size = p.get("size", [0, 0])
            out.append(Patch(id=p["id"], width=size[0], height=size[1], n_images=p.get("n_images", 0),
                             rejected=p.get("rejected", 0), levels=p.get("levels", 0),
                             closed_by=p.get("closed_by", ""), image=os.path.join(self.path, p["image"]),
                             sidecar=os.path.join(self.path, p["sidecar"]), linked=p.get("linked", False),
                             problem=p.get("problem")))
        return out

    @property
    def global_record(self) -> GlobalRecord:
        g = self._info["global"]
        gt = g.get("geotransform")
        return GlobalRecord(width=g["size"][0], height=g["size"][1], n_images=g.get("n_images", 0),
                            n_patches=g.get("n_patches", 0), scale=g.get("scale", 1.0), crs=g.get("crs"),
                            geotransform=tuple(gt) if gt else None)

    @property
    def mosaic_path(self) -> Optional[str]:
        """``mosaic.tif`` when the store has been composed, else None."""
        p = os.path.join(self.path, "mosaic.tif")
        return p if os.path.exists(p) else None

    def sidecar(self, patch_id: int) -> dict:
        """A patch's sidecar (frames, placements, links) as a dictionary."""
        for p in self.patches:
            if p.id == patch_id:
                try:
                    with open(p.sidecar) as f:
                        return json.load(f)
                except (OSError, ValueError) as e:
                    raise Error(f"{p.sidecar}: {e}") from None
        raise Error(f"{self.path}: has no patch {patch_id}")

    def frames(self, patch: Optional[int] = None) -> List[Frame]:
        """Every placed frame (or those of one patch), in patch then sequence order. A patch whose
        sidecar cannot be read raises Error naming it."""
        out = []
        for p in self.patches:
            if patch is not None and p.id != patch:
                continue
            s = self.sidecar(p.id)
            to_mosaic = _matrix(s.get("patch_to_global"))
            for f in s.get("frames", []):
                own = _matrix(f.get("frame_to_global"))
                H = _matrix(f["frame_to_patch"])
                mosaic = None
                if to_mosaic is not None:
                    mosaic = to_mosaic @ H
                out.append(Frame(patch=p.id, index=f["index"], source=f["source"], keyframe=f.get("keyframe", True),
                                 frame_to_patch=H, frame_to_mosaic=mosaic, aligned=own is not None,
                                 inliers=f.get("inliers", 0), registered_by=f.get("registered_by"),
                                 blended=f.get("keyframe", True) and f.get("blended", True)))
        return out

    # ---- georeference ------------------------------------------------------------------------

    @property
    def georeferenced(self) -> bool:
        return self.global_record.geotransform is not None

    def _geotransform(self) -> np.ndarray:
        gt = self.global_record.geotransform
        if gt is None:
            raise Error(f"{self.path}: the mosaic is not georeferenced (compose --navigation or --altitude)")
        return np.asarray(gt, dtype=float)

    def pixel_to_map(self, x, y):
        """Mosaic level-0 pixel coordinates (column, row; arrays welcome) -> map coordinates in
        the mosaic's CRS (``global_record.crs``), by its GDAL geotransform."""
        g = self._geotransform()
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        return g[0] + x * g[1] + y * g[2], g[3] + x * g[4] + y * g[5]

    def map_to_pixel(self, e, n):
        """Map coordinates in the mosaic's CRS -> mosaic level-0 pixel coordinates (column, row)."""
        g = self._geotransform()
        A = np.array([[g[1], g[2]], [g[4], g[5]]])
        if abs(np.linalg.det(A)) < 1e-300:
            raise Error(f"{self.path}: the mosaic's geotransform is singular")
        inv = np.linalg.inv(A)
        de, dn = np.asarray(e, dtype=float) - g[0], np.asarray(n, dtype=float) - g[3]
        return inv[0, 0] * de + inv[0, 1] * dn, inv[1, 0] * de + inv[1, 1] * dn

    # ---- objects -------------------------------------------------------------------------------

    def detections(self) -> Optional[Dict[str, Any]]:
        """The detections ``rolamos objects detect`` wrote (a GeoJSON FeatureCollection as a
        dictionary; map coordinates when the mosaic is georeferenced), or None when there are none."""
        return self._objects_layer("detections.geojson")

    def density(self) -> Optional[Dict[str, Any]]:
        """The density layer ``rolamos objects detect`` wrote (GeoJSON cells with ``count``,
        ``density`` per m² or per megapixel, ``area``), or None when there is none."""
        return self._objects_layer("density.geojson")

    def _objects_layer(self, name: str) -> Optional[Dict[str, Any]]:
        path = os.path.join(self.path, "objects", name)
        if not os.path.exists(path):
            return None
        try:
            with open(path) as f:
                return json.load(f)
        except (OSError, ValueError) as e:
            raise Error(f"{path}: {e}") from None

    def __repr__(self) -> str:
        return f"rolamos.Store({self.path!r}: {len(self._info['patches'])} patches)"


def open_image(path_or_store: Union[PathLike, Store], name: Union[str, int] = "mosaic",
               cache_mb: float = 256.0) -> Image:
    """An image to read from: a store's ``"mosaic"`` or a patch (its id, or ``"patch-N"``), or
    any tiled image file. Reads go through a tile cache of at most ``cache_mb`` megabytes."""
    if isinstance(path_or_store, Store):
        store = path_or_store
    else:
        path = os.fspath(path_or_store)
        if not os.path.exists(path):
            raise Error(f"{path}: no such file or store")
        if not os.path.isdir(path):
            return Image(path, cache_mb)
        store = Store(path)
    if name == "mosaic":
        if store.mosaic_path is None:
            raise Error(f"{store.path}: has no mosaic.tif yet (run compose first)")
        return Image(store.mosaic_path, cache_mb)
    try:
        patch_id = int(name[6:]) if isinstance(name, str) and name.startswith("patch-") else int(name)
    except ValueError:
        raise ValueError(f"name {name!r}: 'mosaic', a patch id or 'patch-N'") from None
    for p in store.patches:
        if p.id == patch_id:
            return Image(p.image, cache_mb)
    raise Error(f"{store.path}: has no patch {patch_id}")
