// libFuzzer target: any bytes as a TIFF through the reader (inspection under allocation caps,
// OpenImageIO tile cache, GDAL georeference), reading every level. It must report an Error or
// succeed; crashes, hangs, leaks of control and huge allocations are bugs.
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <string>

#include "rolamos/error.hpp"
#include "rolamos/tiled_image.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static auto cache = [] {
    rolamos::TileCacheOptions o;
    o.max_memory_mb = 64;
    return std::make_shared<rolamos::TileCache>(o);
  }();
  static int counter = 0;
  const std::string path = "/tmp/rolamos-fuzz-tiff-" + std::to_string(getpid()) + "-" +
                           std::to_string(counter++) + ".tif";
  FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) return 0;
  std::fwrite(data, 1, size, f);
  std::fclose(f);
  try {
    rolamos::TiledImage image = rolamos::TiledImage::Open(path, cache);
    for (int k = 0; k < image.num_levels(); ++k) {
      const auto& l = image.info().levels[static_cast<size_t>(k)];
      const int w = static_cast<int>(std::min<long long>(l.width, 300));
      const int h = static_cast<int>(std::min<long long>(l.height, 300));
      try {
        image.ReadRegion(k, cv::Rect(0, 0, w, h));
      } catch (const rolamos::Error&) {
      }
    }
  } catch (const rolamos::Error&) {
  }
  cache->Invalidate(path);
  std::remove(path.c_str());
  return 0;
}
