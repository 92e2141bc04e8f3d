#include "util/codecs.h"

#include <atomic>
#include <mutex>

#include "util/full_module.h"

namespace rolamos {

namespace {
// Set before main() by codecs_opencv.cc when it is linked in: constant-initialised, so no
// ordering question between the two files' static initialisers.
std::atomic<const CodecTable*> g_linked{nullptr};

const CodecTable& Codecs() {
  if (const CodecTable* t = g_linked.load(std::memory_order_acquire)) return *t;
  static std::once_flag once;
  static const CodecTable* loaded = nullptr;
  std::call_once(once, [] {
    using Getter = const CodecTable* (*)();
    loaded = reinterpret_cast<Getter>(FullModuleSymbol("rolamos_codecs"))();
  });
  return *loaded;
}
}  // namespace

void ProvideCodecs(const CodecTable* table) { g_linked.store(table, std::memory_order_release); }
bool CodecsLinkedIn() { return g_linked.load(std::memory_order_acquire) != nullptr; }

void RequireCodecs() { Codecs(); }

cv::Mat ReadImageFile(const std::string& path, int flags) { return Codecs().read_image(path, flags); }

bool EncodeImage(const std::string& extension, const cv::Mat& image, std::vector<unsigned char>* bytes) {
  return Codecs().encode_image(extension, image, bytes);
}

std::unique_ptr<VideoReader> OpenVideo(const std::string& name, int api) { return Codecs().open_video(name, api); }

}  // namespace rolamos
