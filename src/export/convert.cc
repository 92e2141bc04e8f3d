#include "rolamos/convert.hpp"

#include <filesystem>

#include "rolamos/error.hpp"
#include "raster/band_source.h"

namespace rolamos {

bool ConvertOptions::IsValid(std::string* error) const {
  if (input.empty() || output.empty()) {
    *error = "convert needs an input and an output";
    return false;
  }
  std::error_code ec;
  if (std::filesystem::exists(output, ec) &&
      std::filesystem::equivalent(input, output, ec)) {
    *error = "output " + output + " is the input";
    return false;
  }
  TileCacheOptions cache;
  cache.max_memory_mb = cache_mb;
  return cache.IsValid(error);
}

ConvertResult ConvertImage(const ConvertOptions& options, const ProgressFn& progress) {
  std::string error;
  if (!options.IsValid(&error)) Fail("convert", error);
  TileCacheOptions cache_options;
  cache_options.max_memory_mb = options.cache_mb;
  auto cache = std::make_shared<TileCache>(cache_options);
  auto source = OpenBandSource(options.input, cache);
  const PixelLayout& layout = source->layout();
  if (!options.tiff.IsValid(layout, &error)) Fail(options.input, error);

  PyramidTiffWriter writer(options.output, layout, options.tiff);
  if (source->georef()) writer.SetGeoref(*source->georef());
  const int band = writer.band_height();
  for (long long y = 0; y < layout.height; y += band) {
    const int rows = static_cast<int>(std::min<long long>(band, layout.height - y));
    writer.WriteBand(source->Read(y, rows));
    if (progress) progress(double(y + rows) / layout.height);
  }
  ConvertResult result;
  result.stats = writer.Finish();
  result.width = layout.width;
  result.height = layout.height;
  result.channels = layout.channels;
  result.reader = source->reader();
  return result;
}

}  // namespace rolamos
