"""rolamos: seafloor maps from a downward-looking underwater camera.

Python bindings of the rolamos library (the same code the ``rolamos`` command calls):

- ``Store(path)``: a map store, its patches and global record;
- ``open_image(path_or_store, name="mosaic")``: any part of a mosaic or patch as NumPy arrays
  (RGB(A), uint8 or uint16), read through the bounded tile cache;
- ``Mosaicker(store, **options)``: the online engine, fed frame by frame.

Library failures raise ``rolamos.Error`` with the library's message (the file and the reason).
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import List, Optional, Tuple, Union

from ._rolamos import Error, Image, Mosaicker, align, compose, describe_image, describe_store
from ._rolamos import export as _export

__all__ = ["Error", "Image", "Mosaicker", "Patch", "Store", "align", "compose", "export", "open_image"]


def export(image: Union[str, os.PathLike, "Image"], output: Union[str, os.PathLike], *, region=None, level: int = -1,
           scale: float = 1.0, progress=None) -> dict:
    """A region (x, y, w, h in level-0 pixels; None: all) of an image (a path or an Image from
    open_image) at full resolution, a level or a scale, to .tif (streamed, pyramidal), .png or .jpg."""
    path = image.path if isinstance(image, Image) else os.fspath(image)
    return _export(path, os.fspath(output), region=None if region is None else [float(v) for v in region],
                   level=level, scale=scale, progress=progress)


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

    def __init__(self, path: Union[str, os.PathLike]):
        self.path = os.fspath(path)
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
                with open(p.sidecar) as f:
                    return json.load(f)
        raise Error(f"{self.path}: has no patch {patch_id}")

    def __repr__(self) -> str:
        return f"rolamos.Store({self.path!r}: {len(self._info['patches'])} patches)"


def open_image(path_or_store: Union[str, os.PathLike, Store], name: Union[str, int] = "mosaic",
               cache_mb: float = 256.0) -> Image:
    """An image to read from: a store's ``"mosaic"`` or a patch (its id, or ``"patch-N"``), or
    any tiled image file. Reads go through a tile cache of at most ``cache_mb`` megabytes."""
    if isinstance(path_or_store, Store):
        store = path_or_store
    else:
        path = os.fspath(path_or_store)
        if not os.path.isdir(path):
            return Image(path, cache_mb)
        store = Store(path)
    if name == "mosaic":
        if store.mosaic_path is None:
            raise Error(f"{store.path}: has no mosaic.tif yet (run compose first)")
        return Image(store.mosaic_path, cache_mb)
    patch_id = int(name[6:]) if isinstance(name, str) and name.startswith("patch-") else int(name)
    for p in store.patches:
        if p.id == patch_id:
            return Image(p.image, cache_mb)
    raise Error(f"{store.path}: has no patch {patch_id}")
