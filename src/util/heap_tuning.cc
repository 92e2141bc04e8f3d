#include "util/heap_tuning.h"

#include <malloc.h>
#include <unistd.h>

#include <cstdlib>
#include <fstream>
#include <sstream>

namespace rolamos {
namespace {

constexpr char kHugePageTunable[] = "glibc.malloc.hugetlb";

}  // namespace

std::optional<std::string> TunablesWithHugePageHeap(const std::string& current) {
  std::stringstream items(current);
  std::string item;
  while (std::getline(items, item, ':')) {
    if (item.compare(0, item.find('='), kHugePageTunable) == 0) return std::nullopt;
  }
  const std::string added = std::string(kHugePageTunable) + "=1";
  return current.empty() ? added : current + ":" + added;
}

bool HugePagesOnRequest(const std::string& thp_enabled) {
  return thp_enabled.find("[madvise]") != std::string::npos;
}

void RestartWithHugePageHeap(char** argv) {
  std::ifstream mode_file("/sys/kernel/mm/transparent_hugepage/enabled");
  std::string mode;
  if (!std::getline(mode_file, mode) || !HugePagesOnRequest(mode)) return;
  const char* current = std::getenv("GLIBC_TUNABLES");
  const auto tunables = TunablesWithHugePageHeap(current ? current : "");
  if (!tunables || setenv("GLIBC_TUNABLES", tunables->c_str(), 1) != 0) return;
  execv("/proc/self/exe", argv);
  // Not re-run (no /proc, say): go on as started, with the variable as it was.
  if (current)
    setenv("GLIBC_TUNABLES", current, 1);
  else
    unsetenv("GLIBC_TUNABLES");
}

void KeepOneHeap() {
  mallopt(M_MMAP_THRESHOLD, 64 << 20);
  mallopt(M_TRIM_THRESHOLD, 128 << 20);
  mallopt(M_ARENA_MAX, 1);
}

}  // namespace rolamos
