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
  // Masks are read where every level has one and the samples hold no alpha of their own.
  bool masks = (r->samples_ == 1 || r->samples_ == 3) && r->bits_ == 8 && s.masks.size() == s.levels.size();
  for (size_t k = 0; masks && k < s.masks.size(); ++k) {
    const int m = s.masks[k];
    const TiffDirectory* d = m >= 0 ? &s.directories[size_t(m)] : nullptr;
    masks = d && d->tiled && int(d->tile_width) == r->levels_[k].tile_width &&
            int(d->tile_height) == r->levels_[k].tile_height && TIFFIsCODECConfigured(d->compression);
  }
  if (masks) {
    for (size_t k = 0; k < s.masks.size(); ++k) r->levels_[k].mask_directory = s.masks[k];
    r->masked_ = true;
  }
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

void TiffTileReader::ReadTile(int directory, bool jpeg_ycbcr, int tx, int ty, cv::Mat& out,
                              const std::string& what) const {
  Lease lease{this, Borrow(directory)};
  Handle* h = lease.handle.get();
  TIFF* tif = h->file->get();
  if (h->directory != directory) {
    h->directory = -1;
    if (!TIFFSetDirectory(tif, tdir_t(directory))) Fail(path_, what + ": " + h->file->TakeError());
    if (jpeg_ycbcr) TIFFSetField(tif, TIFFTAG_JPEGCOLORMODE, JPEGCOLORMODE_RGB);
    h->directory = directory;
  }
  uint32_t tw = 0, th = 0;
  TIFFGetField(tif, TIFFTAG_TILEWIDTH, &tw);
  TIFFGetField(tif, TIFFTAG_TILELENGTH, &th);
  const uint32_t index = TIFFComputeTile(tif, uint32_t(tx) * tw, uint32_t(ty) * th, 0, 0);
  if (TIFFGetStrileByteCount(tif, index) > 0) {
    const tmsize_t bytes = tmsize_t(out.total() * out.elemSize());
    if (TIFFReadEncodedTile(tif, index, out.data, bytes) < 0) {
      const std::string why = h->file->TakeError();
      h->directory = -1;  // the handle may be left mid-tile
      Fail(path_, what + " cannot be decoded: " + (why.empty() ? "libtiff gave no reason" : why));
    }
  }
}

cv::Mat TiffTileReader::DecodeTile(int level, int tx, int ty) const {
  const Level& l = levels_[size_t(level)];
  const std::string where =
      "level " + std::to_string(level) + " tile (" + std::to_string(tx) + ", " + std::to_string(ty) + ")";
  cv::Mat tile(l.tile_height, l.tile_width, CV_MAKETYPE(bits_ == 16 ? CV_16U : CV_8U, samples_), cv::Scalar::all(0));
  ReadTile(l.directory, l.jpeg_ycbcr, tx, ty, tile, where);
  if (!masked_) return tile;
  // The mask's packed bits (the leftmost pixel in the highest bit) as an alpha sample.
  cv::Mat bits(l.tile_height, (l.tile_width + 7) / 8, CV_8UC1, cv::Scalar(0));
  ReadTile(l.mask_directory, false, tx, ty, bits, "the mask of " + where);
  cv::Mat alpha(tile.size(), CV_8UC1);
  for (int y = 0; y < alpha.rows; ++y) {
    const uchar* b = bits.ptr<uchar>(y);
    uchar* a = alpha.ptr<uchar>(y);
    for (int x = 0; x < alpha.cols; ++x) a[x] = (b[x >> 3] >> (7 - (x & 7))) & 1 ? 255 : 0;
  }
  cv::Mat with_alpha;
  const cv::Mat parts[] = {tile, alpha};
  cv::merge(parts, 2, with_alpha);
  return with_alpha;
}

}  // namespace rolamos
