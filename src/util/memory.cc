#include "util/memory.h"

#include <fstream>
#include <string>

namespace rolamos {
namespace {

double ReadStatusKb(const char* key) {
  std::ifstream in("/proc/self/status");
  std::string line;
  const std::string prefix = std::string(key) + ":";
  while (std::getline(in, line)) {
    if (line.compare(0, prefix.size(), prefix) == 0) return std::stod(line.substr(prefix.size()));
  }
  return 0.0;
}

}  // namespace

double PeakRssMb() { return ReadStatusKb("VmHWM") / 1024.0; }
double CurrentRssMb() { return ReadStatusKb("VmRSS") / 1024.0; }

}  // namespace rolamos
