// Structural reading of a TIFF with libtiff under allocation caps: the IFD chain, each IFD's
// layout, and a check that every tile lies inside the file (truncation is found at open, with
// the tile and the byte counts, not as a decode error later).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace rolamos {

struct TiffDirectory {
  int index = 0;
  uint32_t width = 0, height = 0;
  bool tiled = false;
  uint32_t tile_width = 0, tile_height = 0;
  uint16_t samples = 0, bits = 0, sample_format = 1, photometric = 0, compression = 1;
  uint16_t planar = 1;
  uint32_t subfile_type = 0;
  bool has_alpha = false;
  bool is_mask = false;
  uint64_t tile_count = 0, missing_tiles = 0, compressed_bytes = 0;
};

struct TiffStructure {
  bool bigtiff = false;
  uint64_t file_size = 0;
  std::vector<TiffDirectory> directories;
  std::vector<int> levels;  // directory indices: full resolution, then reduced levels
  // Per level, the directory of its transparency mask (1 bit, the level's size; GDAL's internal
  // masks, Compression::kJpegMask), or -1.
  std::vector<int> masks;
};

bool HasTiffSignature(const std::string& path);
// Throws Error naming the file and the problem.
TiffStructure InspectTiff(const std::string& path);
std::string TiffCompressionName(uint16_t compression);

}  // namespace rolamos
