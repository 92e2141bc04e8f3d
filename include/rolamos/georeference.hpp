// Georeferencing a composed mosaic from per-frame navigation: each frame's pixel -> map affine
// (as in a GeoTIFF, or a CSV of them) against where the frame lies in the mosaic, fitted as one
// similarity transform over all frames; the mosaic gets its CRS and geotransform.
#pragma once

#include <map>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "rolamos/georef_io.hpp"
#include "rolamos/store.hpp"

namespace rolamos {

// A frame's navigation: pixel (col, row) -> map (x, y), and its CRS.
struct FrameNavigation {
  std::string crs;  // "EPSG:32755"
  std::array<double, 6> geotransform{};
};

// Reads a CSV with the columns frame, epsg, gt0..gt5 (GDAL geotransform order; headers may carry
// a suffix, as gt1_dE_dcol) and optionally sequence. Keys: "sequence/frame" or "frame".
// Throws Error naming the file, the line and the column.
//
// With `skipped` (these readers alike), for a CSV that grows while a live run reads it: a line
// that does not parse is left out and described there ("FILE:LINE: reason") instead of failing
// the read, the last line is left for later when its newline is not yet written, and no line at
// all is no error. The header must still be right.
std::map<std::string, FrameNavigation> ReadFrameNavigationCsv(const std::string& path,
                                                              std::vector<std::string>* skipped = nullptr);

// The camera the navigation needs to turn a position into a frame's footprint: a nadir camera
// with focal length `focal_px` (pixels) and principal point (cx, cy) (< 0: the frame's centre).
struct NavigationCamera {
  double focal_px = 0;
  double cx = -1, cy = -1;
  int width = 0, height = 0;  // frame size, for the default principal point
  bool IsValid(std::string* error) const;
};

// `camera` with the frame size of the store's frames filled in (for the default principal point).
NavigationCamera FrameCamera(const Store& store, NavigationCamera camera);

// Reads a vehicle navigation CSV: a frame column (`frame`, `file` or `image`: the frame's file
// name), a position as easting,northing (with an `epsg` column or `crs`) or
// lat,lon (WGS 84: converted to the UTM zone of the first fix), altitude above the seabed
// (metres) and heading (degrees clockwise from north, the direction of the image's top). Each
// frame gets the pixel -> map affine of a nadir camera there (pixel size = altitude / focal).
// Throws Error naming the file, the line and the column.
std::map<std::string, FrameNavigation> ReadVehicleNavigationCsv(const std::string& path,
                                                                const NavigationCamera& camera,
                                                                const std::string& crs = "",
                                                                std::vector<std::string>* skipped = nullptr);

// Either kind of CSV, told apart by its header (gt0..gt5 columns: per-frame affines).
std::map<std::string, FrameNavigation> ReadNavigationCsv(const std::string& path, const NavigationCamera& camera,
                                                         const std::string& crs = "",
                                                         std::vector<std::string>* skipped = nullptr);

struct GeoreferenceResult {
  Georef georef;
  int frames_used = 0;
  double median_residual_m = 0;
  double max_residual_m = 0;
};

// Fits the mosaic's georeference from the frames of its placed patches (compose first) and
// writes it into mosaic.tif and the global record. Throws Error when fewer than two frames have
// navigation or their CRSs differ.
GeoreferenceResult GeoreferenceMosaic(Store store, const std::map<std::string, FrameNavigation>& nav);

// Without navigation: a local engineering frame in metres (kLocalCrsWkt), x along the first
// frame's columns and y against its rows, origin at the first frame's centre, pixel size
// altitude / focal (metres per frame pixel, divided by the mosaic's scale). Throws Error without a
// mosaic or with a non-positive pixel size.
inline constexpr const char* kLocalCrsWkt =
    "LOCAL_CS[\"rolamos local engineering frame (metres from the first frame)\",UNIT[\"metre\",1],"
    "AXIS[\"x\",EAST],AXIS[\"y\",NORTH]]";
Georef GeoreferenceLocal(Store store, double metres_per_frame_pixel);

}  // namespace rolamos
