#include "raster/tiff_file.h"

#include <cstdarg>
#include <cstdio>
#include <cstring>

#include "rolamos/error.hpp"

namespace rolamos {
namespace {

struct OptionsDeleter {
  void operator()(TIFFOpenOptions* o) const { TIFFOpenOptionsFree(o); }
};

std::unique_ptr<TIFFOpenOptions, OptionsDeleter> MakeOptions(void* self,
                                                             TIFFErrorHandlerExtR on_error,
                                                             TIFFErrorHandlerExtR on_warning) {
  std::unique_ptr<TIFFOpenOptions, OptionsDeleter> o(TIFFOpenOptionsAlloc());
  TIFFOpenOptionsSetMaxSingleMemAlloc(o.get(), kTiffMaxSingleAlloc);
  TIFFOpenOptionsSetErrorHandlerExtR(o.get(), on_error, self);
  TIFFOpenOptionsSetWarningHandlerExtR(o.get(), on_warning, self);
  return o;
}

}  // namespace

int TiffFile::OnError(TIFF*, void* self, const char* module, const char* fmt, va_list ap) {
  auto* f = static_cast<TiffFile*>(self);
  char buf[1024];
  std::vsnprintf(buf, sizeof buf, fmt, ap);
  if (!f->errors_.empty()) f->errors_ += "; ";
  f->errors_ += buf;
  return 1;  // handled: nothing reaches stderr
}

int TiffFile::OnWarning(TIFF*, void*, const char*, const char*, va_list) { return 1; }

std::unique_ptr<TiffFile> TiffFile::Open(const std::string& path, const char* mode) {
  std::unique_ptr<TiffFile> f(new TiffFile());
  f->path_ = path;
  auto opts = MakeOptions(f.get(), &TiffFile::OnError, &TiffFile::OnWarning);
  f->tif_ = TIFFOpenExt(path.c_str(), mode, opts.get());
  if (!f->tif_) {
    std::string why = f->errors_.empty() ? "not a TIFF file or cannot be opened" : f->errors_;
    Fail(path, why);
  }
  return f;
}

std::unique_ptr<TiffFile> TiffFile::OpenMemory(const char* mode) {
  std::unique_ptr<TiffFile> f(new TiffFile());
  f->path_ = "<memory>";
  f->memory_.reserve(1 << 20);
  auto opts = MakeOptions(f.get(), &TiffFile::OnError, &TiffFile::OnWarning);
  f->tif_ = TIFFClientOpenExt("memory", mode, reinterpret_cast<thandle_t>(f.get()), MemRead,
                              MemWrite, MemSeek, MemClose, MemSize, MemMap, MemUnmap, opts.get());
  if (!f->tif_) Fail("in-memory TIFF", f->errors_);
  return f;
}

TiffFile::~TiffFile() {
  if (tif_) TIFFCleanup(tif_);
}

std::string TiffFile::TakeError() {
  std::string e;
  e.swap(errors_);
  return e;
}

void TiffFile::Close() {
  if (!tif_) return;
  TIFF* t = tif_;
  tif_ = nullptr;
  TIFFClose(t);
  if (!errors_.empty()) Fail(path_, TakeError());
}

void TiffFile::Discard() {
  if (tif_) TIFFCleanup(tif_);
  tif_ = nullptr;
}

tmsize_t TiffFile::MemRead(thandle_t h, void* buf, tmsize_t size) {
  auto* f = reinterpret_cast<TiffFile*>(h);
  if (f->mem_pos_ >= f->memory_.size()) return 0;
  size_t n = std::min<size_t>(static_cast<size_t>(size), f->memory_.size() - f->mem_pos_);
  std::memcpy(buf, f->memory_.data() + f->mem_pos_, n);
  f->mem_pos_ += n;
  return static_cast<tmsize_t>(n);
}

tmsize_t TiffFile::MemWrite(thandle_t h, void* buf, tmsize_t size) {
  auto* f = reinterpret_cast<TiffFile*>(h);
  size_t end = f->mem_pos_ + static_cast<size_t>(size);
  if (end > f->memory_.size()) f->memory_.resize(end);
  std::memcpy(f->memory_.data() + f->mem_pos_, buf, static_cast<size_t>(size));
  f->mem_pos_ = end;
  return size;
}

toff_t TiffFile::MemSeek(thandle_t h, toff_t off, int whence) {
  auto* f = reinterpret_cast<TiffFile*>(h);
  switch (whence) {
    case SEEK_SET: f->mem_pos_ = off; break;
    case SEEK_CUR: f->mem_pos_ += off; break;
    case SEEK_END: f->mem_pos_ = f->memory_.size() + off; break;
  }
  return f->mem_pos_;
}

int TiffFile::MemClose(thandle_t) { return 0; }
toff_t TiffFile::MemSize(thandle_t h) { return reinterpret_cast<TiffFile*>(h)->memory_.size(); }
int TiffFile::MemMap(thandle_t, void**, toff_t*) { return 0; }
void TiffFile::MemUnmap(thandle_t, void*, toff_t) {}

}  // namespace rolamos
