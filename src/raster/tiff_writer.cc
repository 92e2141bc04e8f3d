#include "rolamos/tiff_writer.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <optional>

#include "rolamos/error.hpp"
#include "raster/downsample.h"
#include "raster/mask_split.h"
#include "raster/tiff_file.h"
#include "raster/tiff_tags.h"
#include "raster/tile_encoder.h"
#include "raster/tiff_writer_whole.h"
#include "util/cpu_time.h"
#include "util/files.h"
#include "util/task_pool.h"

namespace rolamos {

bool TiffWriteOptions::IsValid(const PixelLayout& layout, std::string* error) const {
  if (!layout.IsValid(error)) return false;
  if (tile_size != 256 && tile_size != 512) {
    *error = "tile size " + std::to_string(tile_size) + " is not supported; use 256 or 512";
    return false;
  }
  if (quality < 1 || quality > 100) {
    *error = "quality " + std::to_string(quality) + " is outside 1..100";
    return false;
  }
  if (zstd_level < 1 || zstd_level > 22) {
    *error = "zstd level " + std::to_string(zstd_level) + " is outside 1..22";
    return false;
  }
  if (deflate_level < 1 || deflate_level > 9) {
    *error = "deflate level " + std::to_string(deflate_level) + " is outside 1..9";
    return false;
  }
  if (webp_method < 0 || webp_method > 6) {
    *error = "webp method " + std::to_string(webp_method) + " is outside 0..6";
    return false;
  }
  if (threads < 0) {
    *error = "thread count cannot be negative";
    return false;
  }
  if (layout.bits == 16 &&
      (compression == Compression::kJpeg || compression == Compression::kJpegMask ||
       compression == Compression::kWebp)) {
    *error = CompressionName(compression) +
             " stores 8-bit samples only; use zstd, deflate or none for 16-bit images";
    return false;
  }
  if (compression == Compression::kWebp && layout.channels < 3) {
    *error = "webp needs colour (3 or 4 channels); use jpeg, zstd or deflate for gray images";
    return false;
  }
  return true;
}

struct PyramidTiffWriter::Impl {
  struct Level {
    long long width = 0, height = 0;
    long long tiles_x = 0, tiles_y = 0;
    long long rows_done = 0;
    cv::Mat acc;  // rows gathered for the next tile row (levels >= 1)
    int acc_rows = 0;
    std::vector<std::pair<uint64_t, uint32_t>> spilled;  // tile -> (offset, size) in spill file
    std::vector<std::pair<uint64_t, uint32_t>> mask_spilled;  // the same for the mask's tiles
  };

  std::string path, tmp_path, spill_path;
  PixelLayout layout;
  // Compression::kJpegMask with alpha: the file's colour IFDs hold `file_layout` (no alpha), and
  // the alpha goes to a mask IFD per level, written after the levels.
  bool masked = false;
  PixelLayout file_layout;
  TiffWriteOptions options;
  std::unique_ptr<TiffFile> file;
  std::mutex file_mutex;
  int spill_fd = -1;
  std::mutex spill_mutex;
  uint64_t spill_size = 0;
  std::vector<Level> levels;
  std::unique_ptr<TileEncoderPool> encoders, mask_encoders;
  std::vector<uint8_t> jpeg_tables;
  std::unique_ptr<TaskPool> pool;
  std::function<void(const std::string&)> before_rename;  // SetGeoref's tags
  bool finished = false;
  TiffWriteStats stats;
  std::atomic<long long> tiles_written{0};
  std::atomic<long long> encode_ns{0};

  void EmitBand(size_t k, const cv::Mat& band);
  void Append(size_t k, const cv::Mat& rows);
  void WriteTile(size_t k, long long index, const std::vector<uint8_t>& bytes);
  std::pair<uint64_t, uint32_t> Spill(const std::vector<uint8_t>& bytes);
  void CopySpilled(const std::vector<std::pair<uint64_t, uint32_t>>& tiles, const std::string& what);
  void Cleanup();
};

void PyramidTiffWriter::Impl::WriteTile(size_t k, long long index,
                                        const std::vector<uint8_t>& bytes) {
  if (k == 0) {
    std::lock_guard<std::mutex> lock(file_mutex);
    if (TIFFWriteRawTile(file->get(), static_cast<uint32_t>(index),
                         const_cast<uint8_t*>(bytes.data()),
                         static_cast<tmsize_t>(bytes.size())) < 0)
      Fail(path, "cannot write tile " + std::to_string(index) + ": " + file->TakeError());
  } else {
    levels[k].spilled[static_cast<size_t>(index)] = Spill(bytes);
  }
  ++tiles_written;
}

std::pair<uint64_t, uint32_t> PyramidTiffWriter::Impl::Spill(const std::vector<uint8_t>& bytes) {
  std::lock_guard<std::mutex> lock(spill_mutex);
  size_t done = 0;
  while (done < bytes.size()) {
    ssize_t n = ::pwrite(spill_fd, bytes.data() + done, bytes.size() - done,
                         static_cast<off_t>(spill_size + done));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) Fail(spill_path, std::string("cannot write a level's tiles: ") + std::strerror(errno));
    done += static_cast<size_t>(n);
  }
  const std::pair<uint64_t, uint32_t> where{spill_size, static_cast<uint32_t>(bytes.size())};
  spill_size += bytes.size();
  return where;
}

void PyramidTiffWriter::Impl::EmitBand(size_t k, const cv::Mat& band) {
  Level& level = levels[k];
  const long long ty = level.rows_done / options.tile_size;
  // Tiles are cut here (a copy each), so the band is free again when this returns and queued
  // work holds no more than its own tiles.
  for (long long tx = 0; tx < level.tiles_x; ++tx) {
    const long long index = ty * level.tiles_x + tx;
    cv::Mat tile = CutFileTile(band, static_cast<int>(tx), options.tile_size);
    pool->Submit([this, k, index, tile] {
      CpuLaps cpu;
      if (!masked) {
        const std::vector<uint8_t> bytes = encoders->Encode(tile);
        encode_ns += cpu.Lap();
        WriteTile(k, index, bytes);
        return;
      }
      cv::Mat colour, bits;
      SplitMask(tile, &colour, &bits);
      const std::vector<uint8_t> bytes = encoders->Encode(colour);
      const std::vector<uint8_t> mask = mask_encoders->Encode(bits);
      encode_ns += cpu.Lap();
      WriteTile(k, index, bytes);
      levels[k].mask_spilled[static_cast<size_t>(index)] = Spill(mask);
    });
  }
  level.rows_done += band.rows;
  if (k + 1 < levels.size()) Append(k + 1, Downsample2x(band, layout.HasAlpha()));
}

void PyramidTiffWriter::Impl::Append(size_t k, const cv::Mat& rows) {
  Level& level = levels[k];
  if (level.acc.empty())
    level.acc.create(options.tile_size, static_cast<int>(level.width), layout.CvType());
  CV_Assert(rows.cols == level.width && level.acc_rows + rows.rows <= options.tile_size);
  rows.copyTo(level.acc.rowRange(level.acc_rows, level.acc_rows + rows.rows));
  level.acc_rows += rows.rows;
  if (level.acc_rows == options.tile_size || level.rows_done + level.acc_rows == level.height) {
    const int n = level.acc_rows;
    level.acc_rows = 0;
    EmitBand(k, level.acc.rowRange(0, n));
  }
}

void PyramidTiffWriter::Impl::CopySpilled(const std::vector<std::pair<uint64_t, uint32_t>>& tiles,
                                          const std::string& what) {
  std::vector<uint8_t> buf;
  for (size_t i = 0; i < tiles.size(); ++i) {
    const auto [offset, size] = tiles[i];
    buf.resize(size);
    size_t done = 0;
    while (done < size) {
      ssize_t n = ::pread(spill_fd, buf.data() + done, size - done,
                          static_cast<off_t>(offset + done));
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) Fail(spill_path, "cannot read back " + what);
      done += static_cast<size_t>(n);
    }
    if (TIFFWriteRawTile(file->get(), static_cast<uint32_t>(i), buf.data(),
                         static_cast<tmsize_t>(size)) < 0)
      Fail(path, "cannot write " + what + ": " + file->TakeError());
  }
}

void PyramidTiffWriter::Impl::Cleanup() {
  if (spill_fd >= 0) {
    ::close(spill_fd);
    ::unlink(spill_path.c_str());
    spill_fd = -1;
  }
}

PyramidTiffWriter::PyramidTiffWriter(const std::string& path, const PixelLayout& layout,
                                     const TiffWriteOptions& options)
    : impl_(std::make_unique<Impl>()) {
  std::string error;
  if (!options.IsValid(layout, &error)) Fail(path, error);
  Impl& m = *impl_;
  m.path = path;
  m.layout = layout;
  m.options = options;
  m.masked = options.compression == Compression::kJpegMask && layout.HasAlpha();
  m.file_layout = layout;
  if (m.masked) --m.file_layout.channels;
  m.tmp_path = TemporarySibling(path);
  m.spill_path = m.tmp_path + ".levels";

  long long w = layout.width, h = layout.height;
  const int t = options.tile_size;
  auto add_level = [&](long long lw, long long lh) {
    Impl::Level level;
    level.width = lw;
    level.height = lh;
    level.tiles_x = (lw + t - 1) / t;
    level.tiles_y = (lh + t - 1) / t;
    m.levels.push_back(std::move(level));
  };
  add_level(w, h);
  while (options.pyramid && std::max(w, h) > t) {
    w = (w + 1) / 2;
    h = (h + 1) / 2;
    add_level(w, h);
  }
  for (size_t k = 0; k < m.levels.size(); ++k) {
    const size_t tiles = static_cast<size_t>(m.levels[k].tiles_x * m.levels[k].tiles_y);
    if (k > 0) m.levels[k].spilled.resize(tiles);
    if (m.masked) m.levels[k].mask_spilled.resize(tiles);
  }

  m.file = TiffFile::Open(m.tmp_path, "w8");  // BigTIFF always
  LevelTags level0;
  level0.width = static_cast<uint32_t>(layout.width);
  level0.height = static_cast<uint32_t>(layout.height);
  level0.mip_tag = !m.masked;
  SetLevelTags(m.file->get(), m.file_layout, options, level0, /*for_encoding=*/false);
  if (m.levels.size() > 1 || m.masked) {
    m.spill_fd = ::open(m.spill_path.c_str(), O_RDWR | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
    if (m.spill_fd < 0) {
      std::string why = std::strerror(errno);
      m.file->Discard();
      ::unlink(m.tmp_path.c_str());
      Fail(m.spill_path, "cannot create temporary file: " + why);
    }
  }
  m.encoders = std::make_unique<TileEncoderPool>(m.file_layout, options);
  if (m.masked) m.mask_encoders = std::make_unique<TileEncoderPool>(m.file_layout, options, /*mask=*/true);
  m.jpeg_tables = m.encoders->JpegTables();
  SetJpegTables(m.file->get(), m.jpeg_tables);
  // About one tile row of queued tiles: enough for the workers to ride out the main thread's
  // downsampling bursts, little enough to keep memory at a band's worth.
  m.pool = std::make_unique<TaskPool>(
      options.threads, static_cast<int>(std::clamp<long long>(m.levels[0].tiles_x / 2 + 8, 24, 96)));
}

PyramidTiffWriter::~PyramidTiffWriter() {
  if (!impl_ || impl_->finished) return;
  try {
    impl_->pool.reset();  // joins the workers
  } catch (...) {
  }
  if (impl_->file) impl_->file->Discard();
  ::unlink(impl_->tmp_path.c_str());
  impl_->Cleanup();
}

int PyramidTiffWriter::band_height() const { return impl_->options.tile_size; }

void PyramidTiffWriter::WriteBand(const cv::Mat& band) {
  Impl& m = *impl_;
  if (m.finished) Fail(m.path, "WriteBand after Finish");
  const auto& level0 = m.levels[0];
  const long long expected = std::min<long long>(m.options.tile_size, level0.height - level0.rows_done);
  if (expected <= 0) Fail(m.path, "more rows than the image height " + std::to_string(level0.height));
  if (band.type() != m.layout.CvType() || band.cols != level0.width || band.rows != expected)
    Fail(m.path, "band " + std::to_string(level0.rows_done / m.options.tile_size) + " is " +
                     std::to_string(band.cols) + "x" + std::to_string(band.rows) + " of type " +
                     std::to_string(band.type()) + "; expected " + std::to_string(level0.width) +
                     "x" + std::to_string(expected) + " of type " +
                     std::to_string(m.layout.CvType()));
  m.EmitBand(0, band);
}

const std::string& PyramidTiffWriter::path() const { return impl_->path; }

void PyramidTiffWriter::BeforeRename(std::function<void(const std::string& tmp_path)> step) {
  impl_->before_rename = std::move(step);
}

TiffWriteStats PyramidTiffWriter::Finish() {
  Impl& m = *impl_;
  if (m.finished) return m.stats;
  if (m.levels[0].rows_done != m.levels[0].height)
    Fail(m.path, "image incomplete: " + std::to_string(m.levels[0].rows_done) + " of " +
                     std::to_string(m.levels[0].height) + " rows were written");
  m.pool->Wait();
  TIFF* tif = m.file->get();
  for (size_t k = 1; k < m.levels.size(); ++k) {
    if (!TIFFWriteDirectory(tif)) Fail(m.path, "cannot write directory: " + m.file->TakeError());
    LevelTags tags;
    tags.width = static_cast<uint32_t>(m.levels[k].width);
    tags.height = static_cast<uint32_t>(m.levels[k].height);
    tags.reduced = true;
    tags.mip_tag = !m.masked;
    SetLevelTags(tif, m.file_layout, m.options, tags, /*for_encoding=*/false);
    SetJpegTables(tif, m.jpeg_tables);
    m.CopySpilled(m.levels[k].spilled, "level " + std::to_string(k));
  }
  // The masks after all the levels: readers that know them pair each with the level of its size
  // (GDAL); OpenImageIO reads the levels as one MIP-mapped image and the masks as another.
  for (size_t k = 0; m.masked && k < m.levels.size(); ++k) {
    if (!TIFFWriteDirectory(tif)) Fail(m.path, "cannot write directory: " + m.file->TakeError());
    LevelTags tags;
    tags.width = static_cast<uint32_t>(m.levels[k].width);
    tags.height = static_cast<uint32_t>(m.levels[k].height);
    tags.reduced = k > 0;
    SetMaskTags(tif, m.options, tags);
    m.CopySpilled(m.levels[k].mask_spilled, "the mask of level " + std::to_string(k));
  }
  m.file->Close();
  m.Cleanup();
  if (m.before_rename) m.before_rename(m.tmp_path);
  RenameFile(m.tmp_path, m.path);
  m.finished = true;
  m.stats.tiles = m.tiles_written;
  m.stats.encode_cpu_seconds = 1e-9 * static_cast<double>(m.encode_ns.load());
  m.stats.levels = static_cast<int>(m.levels.size());
  std::error_code ec;
  m.stats.bytes = static_cast<long long>(std::filesystem::file_size(m.path, ec));
  return m.stats;
}

TiffWriteStats WritePyramidTiff(const std::string& path, const cv::Mat& image, const TiffWriteOptions& options) {
  return WriteWholeTiff(path, image, options, [](PyramidTiffWriter&) {});
}

TiffWriteStats WriteWholeTiff(const std::string& path, const cv::Mat& image, const TiffWriteOptions& options,
                              const std::function<void(PyramidTiffWriter&)>& configure) {
  PixelLayout layout;
  layout.width = image.cols;
  layout.height = image.rows;
  layout.channels = image.channels();
  layout.bits = image.depth() == CV_16U ? 16 : (image.depth() == CV_8U ? 8 : 0);
  PyramidTiffWriter writer(path, layout, options);
  configure(writer);
  for (int y = 0; y < image.rows; y += writer.band_height())
    writer.WriteBand(image.rowRange(y, std::min(image.rows, y + writer.band_height())));
  return writer.Finish();
}

}  // namespace rolamos
