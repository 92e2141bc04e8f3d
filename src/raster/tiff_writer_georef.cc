// The TIFF writer's georeference, apart from the writer (tiff_writer.cc): its tags are written
// through GDAL, which a mosaic run's patches never need and its program is linked without
// (tools/main.cc).
#include "raster/tiff_writer_whole.h"
#include "rolamos/error.hpp"
#include "rolamos/tiff_writer.hpp"

namespace rolamos {

void PyramidTiffWriter::SetGeoref(const Georef& georef) {
  std::string error;
  if (!georef.IsValid(&error)) Fail(path(), "georeference: " + error);
  BeforeRename([georef](const std::string& tmp_path) { WriteGeoref(tmp_path, georef); });
}

TiffWriteStats WritePyramidTiff(const std::string& path, const cv::Mat& image, const TiffWriteOptions& options,
                                const Georef* georef) {
  return WriteWholeTiff(path, image, options, [georef](PyramidTiffWriter& writer) {
    if (georef) writer.SetGeoref(*georef);
  });
}

}  // namespace rolamos
