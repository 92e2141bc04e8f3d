#include "util/full_module.h"

#include <dlfcn.h>
#include <unistd.h>

#include <filesystem>
#include <mutex>

#include "rolamos/error.hpp"

namespace rolamos {

namespace {
constexpr const char* kModuleName = "librolamos_full.so";

std::string ProgramDirectory() {
  std::error_code ec;
  const std::filesystem::path self = std::filesystem::read_symlink("/proc/self/exe", ec);
  return ec ? std::string(".") : self.parent_path().string();
}
}  // namespace

std::string FullModulePath() {
  const std::string dir = ProgramDirectory();
  const std::string beside = dir + "/" + kModuleName;
  const std::string installed = dir + "/../lib/rolamos/" + kModuleName;
  std::error_code ec;
  if (!std::filesystem::exists(beside, ec) && std::filesystem::exists(installed, ec)) return installed;
  return beside;
}

void* FullModuleSymbol(const char* name) {
  static std::mutex mutex;
  static void* handle = nullptr;
  static std::string path;
  std::lock_guard<std::mutex> lock(mutex);
  if (!handle) {
    path = FullModulePath();
    // RTLD_LOCAL: the module's own copy of the library stays its own; only the symbols asked
    // for here cross over. RTLD_DEEPBIND: the ~230 libraries it brings resolve their symbols in
    // its own scope first, heaviest first (cmake/link_order.cmake), not after the launcher's 51
    // libraries: `rolamos info` 0.23-0.33 -> 0.16-0.20 s, as the one binary started before.
    handle = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL | RTLD_DEEPBIND);
    if (!handle) {
      const char* why = dlerror();
      Fail(path, std::string("cannot be loaded (it holds the commands and codecs the launcher leaves out): ") +
                     (why ? why : "unknown error"));
    }
  }
  dlerror();
  void* symbol = dlsym(handle, name);
  if (!symbol) Fail(path, std::string("has no symbol ") + name + ": built from another version of rolamos?");
  return symbol;
}

}  // namespace rolamos
