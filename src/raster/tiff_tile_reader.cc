#include "raster/tiff_tile_reader.h"

#include "rolamos/error.hpp"

namespace rolamos {

std::unique_ptr<TiffTileReader> TiffTileReader::TryOpen(const std::string& path, const TiffStructure& s) {
  std::unique_ptr<TiffTileReader> r(new TiffTileReader());
  r->path_ = path;
  for (int dir : s.levels) {
    const TiffDirectory& d = s.directories[size_t(dir)];
    if (!d.tiled || d.planar != PLANARCONFIG_CONTIG || d.sample_format != SAMPLEFORMAT_UINT) return nullptr;
    if (d.bits != 8 && d.bits != 16) return nullptr;
    const bool ycbcr_jpeg = d.photometric == PHOTOMETRIC_YCBCR && d.compression == COMPRESSION_JPEG && d.bits == 8;
    if (d.photometric != PHOTOMETRIC_MINISBLACK && d.photometric != PHOTOMETRIC_RGB && !ycbcr_jpeg) return nullptr;
    if (d.samples < 1 || d.samples > 4 || d.tile_width == 0 || d.tile_height == 0) return nullptr;
    if (!r->levels_.empty() && (d.samples != r->samples_ || d.bits != r->bits_)) return nullptr;
    r->samples_ = d.samples;
    r->bits_ = d.bits;
    r->levels_.push_back({dir, int(d.tile_width), int(d.tile_height), d.width, d.height, ycbcr_jpeg});
    // A codec libtiff was built without: OpenImageIO's path reports it.
    if (!TIFFIsCODECConfigured(d.compression)) return nullptr;
  }
  if (r->levels_.empty()) return nullptr;
  // Held from now on: reads go on if the file is deleted or replaced later.
  auto first = std::make_unique<Handle>();
  first->file = TiffFile::Open(path, "r");
  r->stamp_ = FileStamp::Of(TIFFFileno(first->file->get()));
  r->idle_.push_back(std::move(first));
  r->open_ = 1;
  return r;
}

TiffTileReader::~TiffTileReader() = default;

std::unique_ptr<TiffTileReader::Handle> TiffTileReader::OpenHandle() const {
  auto h = std::make_unique<Handle>();
  h->file = TiffFile::Open(path_, "r");
  if (!(FileStamp::Of(TIFFFileno(h->file->get())) == stamp_))
    Fail(path_, "was replaced or changed since it was opened: open it again");
  return h;
}

std::unique_ptr<TiffTileReader::Handle> TiffTileReader::Borrow(int directory) const {
  std::unique_lock<std::mutex> lock(mutex_);
  const auto take = [&]() {
    // One already at the directory saves reading it again.
    auto it = idle_.begin();
    for (; it != idle_.end(); ++it)
      if ((*it)->directory == directory) break;
    if (it == idle_.end()) --it;
    std::unique_ptr<Handle> h = std::move(*it);
    idle_.erase(it);
    return h;
  };
  if (!idle_.empty()) return take();
  if (open_ < kMaxHandles) {
    ++open_;
    lock.unlock();
    try {
      return OpenHandle();
    } catch (const Error&) {
      lock.lock();
      --open_;
      if (open_ == 0) throw;  // none open to wait for
    }
  }
  returned_.wait(lock, [&] { return !idle_.empty(); });
  return take();
}

void TiffTileReader::Return(std::unique_ptr<Handle> h) const {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    idle_.push_back(std::move(h));
  }
  returned_.notify_one();
}

cv::Mat TiffTileReader::DecodeTile(int level, int tx, int ty) const {
  const Level& l = levels_[size_t(level)];
  const auto where = [&] {
    return "level " + std::to_string(level) + " tile (" + std::to_string(tx) + ", " + std::to_string(ty) + ")";
  };
  Lease lease{this, Borrow(l.directory)};
  Handle* h = lease.handle.get();
  TIFF* tif = h->file->get();
  if (h->directory != l.directory) {
    h->directory = -1;
    if (!TIFFSetDirectory(tif, tdir_t(l.directory))) Fail(path_, where() + ": " + h->file->TakeError());
    if (l.jpeg_ycbcr) TIFFSetField(tif, TIFFTAG_JPEGCOLORMODE, JPEGCOLORMODE_RGB);
    h->directory = l.directory;
  }
  cv::Mat tile(l.tile_height, l.tile_width, CV_MAKETYPE(bits_ == 16 ? CV_16U : CV_8U, samples_), cv::Scalar::all(0));
  const uint32_t index = TIFFComputeTile(tif, uint32_t(tx) * uint32_t(l.tile_width),
                                         uint32_t(ty) * uint32_t(l.tile_height), 0, 0);
  if (TIFFGetStrileByteCount(tif, index) > 0) {
    const tmsize_t bytes = tmsize_t(tile.total() * tile.elemSize());
    if (TIFFReadEncodedTile(tif, index, tile.data, bytes) < 0) {
      const std::string why = h->file->TakeError();
      h->directory = -1;  // the handle may be left mid-tile
      Fail(path_, where() + " cannot be decoded: " + (why.empty() ? "libtiff gave no reason" : why));
    }
  }
  return tile;
}

}  // namespace rolamos
