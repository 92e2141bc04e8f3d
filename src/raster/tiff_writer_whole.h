// An image already in memory written by PyramidTiffWriter, the writer first set up by `configure`:
// both WritePyramidTiff overloads (tiff_writer.cc, and tiff_writer_georef.cc, which sets the
// georeference).
#pragma once

#include <functional>
#include <string>

#include "rolamos/tiff_writer.hpp"

namespace rolamos {

TiffWriteStats WriteWholeTiff(const std::string& path, const cv::Mat& image, const TiffWriteOptions& options,
                              const std::function<void(PyramidTiffWriter&)>& configure);

}  // namespace rolamos
