#include "raster/band_source.h"

#include <gdal_priv.h>

#include <filesystem>

#include "rolamos/error.hpp"
#include "rolamos/tiled_image.hpp"
#include "raster/gdal_setup.h"
#include "raster/tiff_file.h"
#include "raster/tiff_inspect.h"

#include <opencv2/imgproc.hpp>

namespace rolamos {
namespace {

class CacheBandSource : public BandSource {
 public:
  explicit CacheBandSource(TiledImage image) : image_(std::move(image)) {
    const auto& info = image_.info();
    layout_.width = image_.width();
    layout_.height = image_.height();
    layout_.channels = info.channels;
    layout_.bits = info.bits;
    georef_ = info.georef;
    reader_ = "openimageio";
  }
  cv::Mat Read(long long y, int rows) override {
    cv::Mat band(rows, static_cast<int>(layout_.width), layout_.CvType());
    // Column chunks aligned to the source tiles, decoded on all cores.
    const int tw = std::max(256, image_.info().levels[0].tile_width);
    const int chunk = tw * std::max(1, static_cast<int>(layout_.width / tw / 8));
    const int n = static_cast<int>((layout_.width + chunk - 1) / chunk);
    cv::parallel_for_(cv::Range(0, n), [&](const cv::Range& r) {
      for (int i = r.start; i < r.end; ++i) {
        const int x0 = i * chunk;
        const int w = std::min<int>(chunk, static_cast<int>(layout_.width) - x0);
        cv::Mat view = band(cv::Rect(x0, 0, w, rows));
        image_.ReadRegionInto(0, cv::Rect(x0, static_cast<int>(y), w, rows), view);
      }
    });
    return band;
  }

 private:
  TiledImage image_;
};

// Tiled TIFFs are streamed with libtiff directly, one handle per core: the tile cache decodes a
// file on one thread at a time, and a sequential pass reads each tile once, so it gains nothing.
class TiffBandSource : public BandSource {
 public:
  TiffBandSource(const std::string& path, const TiffDirectory& d, std::optional<Georef> georef)
      : path_(path), dir_(d) {
    layout_.width = d.width;
    layout_.height = d.height;
    layout_.channels = d.samples;
    layout_.bits = d.bits;
    georef_ = std::move(georef);
    reader_ = "libtiff";
    const int n = std::max(1, cv::getNumThreads());
    for (int i = 0; i < n; ++i) {
      handles_.push_back(TiffFile::Open(path, "rm"));  // "m": read, not map: RSS stays small
      if (d.photometric == PHOTOMETRIC_YCBCR && d.compression == COMPRESSION_JPEG)
        TIFFSetField(handles_.back()->get(), TIFFTAG_JPEGCOLORMODE, JPEGCOLORMODE_RGB);
    }
  }
  static bool Supports(const TiffDirectory& d) {
    return d.tiled && d.planar == PLANARCONFIG_CONTIG && d.sample_format == SAMPLEFORMAT_UINT &&
           (d.bits == 8 || d.bits == 16) && d.samples >= 1 && d.samples <= 4 &&
           (d.photometric == PHOTOMETRIC_MINISBLACK || d.photometric == PHOTOMETRIC_RGB ||
            (d.photometric == PHOTOMETRIC_YCBCR && d.compression == COMPRESSION_JPEG)) &&
           d.missing_tiles == 0;
  }
  cv::Mat Read(long long y, int rows) override {
    cv::Mat band(rows, static_cast<int>(layout_.width), layout_.CvType());
    const int tw = static_cast<int>(dir_.tile_width), th = static_cast<int>(dir_.tile_height);
    const int tiles_x = static_cast<int>((layout_.width + tw - 1) / tw);
    const int n = static_cast<int>(handles_.size());
    cv::parallel_for_(cv::Range(0, n), [&](const cv::Range& r) {
      for (int part = r.start; part < r.end; ++part) {
        TiffFile& file = *handles_[static_cast<size_t>(part)];
        cv::Mat tile(th, tw, layout_.CvType());
        for (int tx = part * tiles_x / n; tx < (part + 1) * tiles_x / n; ++tx) {
          // A band may start inside a tile row (other tile heights than ours): copy the overlap.
          for (long long ty0 = (y / th) * th; ty0 < y + rows; ty0 += th) {
            const uint32_t index = TIFFComputeTile(file.get(), static_cast<uint32_t>(tx * tw),
                                                   static_cast<uint32_t>(ty0), 0, 0);
            if (TIFFReadEncodedTile(file.get(), index, tile.data,
                                    static_cast<tmsize_t>(tile.total() * tile.elemSize())) < 0)
              Fail(path_, "tile " + std::to_string(index) + " cannot be decoded: " +
                              file.TakeError());
            const int x0 = tx * tw, w = std::min<int>(tw, static_cast<int>(layout_.width) - x0);
            const long long r0 = std::max(ty0, y), r1 = std::min(ty0 + th, y + rows);
            cv::Mat src = tile(cv::Rect(0, static_cast<int>(r0 - ty0), w, static_cast<int>(r1 - r0)));
            cv::Mat dst = band(cv::Rect(x0, static_cast<int>(r0 - y), w, static_cast<int>(r1 - r0)));
            if (layout_.channels == 3) cv::cvtColor(src, dst, cv::COLOR_RGB2BGR);
            else if (layout_.channels == 4) cv::cvtColor(src, dst, cv::COLOR_RGBA2BGRA);
            else src.copyTo(dst);
          }
        }
      }
    }, n);
    return band;
  }

 private:
  std::string path_;
  TiffDirectory dir_;
  std::vector<std::unique_ptr<TiffFile>> handles_;
};

class GdalBandSource : public BandSource {
 public:
  GdalBandSource(const std::string& path, double cache_mb) : path_(path) {
    EnsureGdal();
    TakeGdalError();
    GDALSetCacheMax64(static_cast<GIntBig>(cache_mb * 1024 * 1024));
    ds_.reset(GDALDataset::Open(path.c_str(), GDAL_OF_RASTER | GDAL_OF_READONLY));
    if (!ds_) Fail(path, "neither OpenImageIO nor GDAL can read it (" + TakeGdalError() + ")");
    const int bands = ds_->GetRasterCount();
    if (bands < 1 || bands > 4)
      Fail(path, std::to_string(bands) + " bands; 1 to 4 can be converted");
    const GDALDataType type = ds_->GetRasterBand(1)->GetRasterDataType();
    if (type != GDT_Byte && type != GDT_UInt16)
      Fail(path, std::string("samples of type ") + GDALGetDataTypeName(type) +
                     " cannot be converted (8 or 16-bit unsigned)");
    layout_.width = ds_->GetRasterXSize();
    layout_.height = ds_->GetRasterYSize();
    layout_.channels = bands;
    layout_.bits = type == GDT_UInt16 ? 16 : 8;
    georef_ = ReadGeoref(path);
    reader_ = "gdal";
    // OpenCV order: B, G, R(, A) from GDAL's R, G, B(, A).
    map_ = {1};
    if (bands == 2) map_ = {1, 2};
    if (bands == 3) map_ = {3, 2, 1};
    if (bands == 4) map_ = {3, 2, 1, 4};
  }
  cv::Mat Read(long long y, int rows) override {
    cv::Mat band(rows, static_cast<int>(layout_.width), layout_.CvType());
    const int esize = layout_.bits / 8;
    const GDALDataType type = layout_.bits == 16 ? GDT_UInt16 : GDT_Byte;
    if (ds_->RasterIO(GF_Read, 0, static_cast<int>(y), static_cast<int>(layout_.width), rows,
                      band.data, static_cast<int>(layout_.width), rows, type,
                      static_cast<int>(map_.size()), map_.data(),
                      static_cast<GSpacing>(esize) * layout_.channels,
                      static_cast<GSpacing>(band.step[0]), esize, nullptr) != CE_None)
      Fail(path_, "rows " + std::to_string(y) + ".." + std::to_string(y + rows) +
                      " cannot be read: " + TakeGdalError());
    return band;
  }

 private:
  std::string path_;
  GDALDatasetUniquePtr ds_;
  std::vector<int> map_;
};

}  // namespace

std::unique_ptr<BandSource> OpenBandSource(const std::string& path,
                                           std::shared_ptr<TileCache> cache) {
  if (!std::filesystem::exists(path)) Fail(path, "no such file");
  if (HasTiffSignature(path)) {
    TiffStructure s = InspectTiff(path);  // refuses truncated and implausible files first
    const TiffDirectory& d0 = s.directories[static_cast<size_t>(s.levels[0])];
    if (TiffBandSource::Supports(d0))
      return std::make_unique<TiffBandSource>(path, d0, ReadGeoref(path));
  }
  std::string oiio_error;
  try {
    return std::make_unique<CacheBandSource>(TiledImage::Open(path, cache));
  } catch (const Error& e) {
    oiio_error = e.what();
  }
  try {
    return std::make_unique<GdalBandSource>(path, cache->options().max_memory_mb);
  } catch (const Error& e) {
    // Report both readers' reasons: the first is usually the telling one.
    Fail(path, std::string("cannot be read. OpenImageIO: ") + oiio_error + ". GDAL: " + e.what());
  }
}

}  // namespace rolamos
