// Wall-clock time as the store's files write it (live/status.json, live/preview.json).
#pragma once

#include <chrono>

namespace rolamos {

// Seconds since the Unix epoch.
inline double UnixNow() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

}  // namespace rolamos
