// A survey as a catalogue entry: a STAC 1.0.0 Item (the map as a Cloud Optimized GeoTIFF and a
// thumbnail, its footprint - the ground it covers, not its bounding box - in WGS 84, the
// projection extension's fields, the ground sample distance and the survey's time span) in a
// STAC Catalog that holds every survey exported into the same directory.
#pragma once

#include <string>

#include "rolamos/progress.hpp"
#include "rolamos/store.hpp"

namespace rolamos {

struct StacOptions {
  std::string id;            // the item's id; "" = the store directory's name
  std::string title;         // "" = the id
  std::string description;   // the catalogue's, when it is created
  // The survey's time span as RFC 3339 "START/END"; "" = from the frames' files (their
  // modification times), or the patches' when the frames are not at hand.
  std::string datetime;
  int thumbnail_px = 512;    // longest side of the thumbnail
  int cog_quality = 90;
  bool IsValid(std::string* error) const;
};

struct StacResult {
  std::string item;     // the item's JSON file
  std::string catalog;  // the catalogue's
  std::string cog, thumbnail;
  int footprint_parts = 0;  // polygons of the footprint (patches apart on the ground)
  std::string time_source;  // "option", "frame files" or "store"
};

// Exports the store's georeferenced mosaic under `dir`/ID/ and adds it to `dir`/catalog.json
// (created when absent, an existing entry of the same id replaced). Throws Error naming the store
// when it has no mosaic or the mosaic has no CRS that places it on Earth.
StacResult ExportStac(const Store& store, const std::string& dir, const StacOptions& options,
                      const ProgressFn& progress = nullptr);

}  // namespace rolamos
