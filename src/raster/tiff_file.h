// A libtiff handle that owns its own error messages (per-handle handlers, libtiff >= 4.5), so a
// failure is reported with the file and libtiff's reason instead of going to stderr.
#pragma once

#include <tiffio.h>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace rolamos {

// Refuses single allocations above this (hostile files): a tile of 8192x8192x4x16-bit.
inline constexpr tmsize_t kTiffMaxSingleAlloc = tmsize_t(512) << 20;

class TiffFile {
 public:
  // mode as TIFFOpen's ("r", "w8", ...). Throws Error naming `path` and libtiff's reason.
  static std::unique_ptr<TiffFile> Open(const std::string& path, const char* mode);
  // A TIFF held in memory (for encoding tiles with libtiff's codecs).
  static std::unique_ptr<TiffFile> OpenMemory(const char* mode);
  ~TiffFile();

  TIFF* get() const { return tif_; }
  const std::string& path() const { return path_; }
  // The messages libtiff gave since the last call ("" if none).
  std::string TakeError();
  // Closes, writing pending directories; throws Error on failure.
  void Close();
  // Drops the handle without writing anything more (memory TIFFs).
  void Discard();

  // Memory TIFFs only: the bytes written so far, and a way to forget all but the header.
  std::vector<uint8_t>& memory() { return memory_; }
  void TruncateMemory(size_t size) { memory_.resize(size); }

 private:
  TiffFile() = default;
  static int OnError(TIFF*, void* self, const char* module, const char* fmt, va_list ap);
  static int OnWarning(TIFF*, void* self, const char* module, const char* fmt, va_list ap);
  static tmsize_t MemRead(thandle_t, void*, tmsize_t);
  static tmsize_t MemWrite(thandle_t, void*, tmsize_t);
  static toff_t MemSeek(thandle_t, toff_t, int);
  static int MemClose(thandle_t);
  static toff_t MemSize(thandle_t);
  static int MemMap(thandle_t, void**, toff_t*);
  static void MemUnmap(thandle_t, void*, toff_t);

  TIFF* tif_ = nullptr;
  std::string path_;
  std::string errors_;
  std::vector<uint8_t> memory_;
  uint64_t mem_pos_ = 0;
};

}  // namespace rolamos
