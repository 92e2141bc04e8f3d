// Progress of long library work, the one type every long call takes: the fraction of the whole
// call that is done, in [0, 1], non-decreasing. It may be called from worker threads (serialise
// inside it if it draws) and should return quickly. An empty function means nobody is listening.
#pragma once

#include <functional>

namespace rolamos {

using ProgressFn = std::function<void(double fraction)>;

// Reports the part [begin, end] of a longer job: Sub(p, 0.5, 1)(0.5) calls p(0.75). For calls
// made of stages (object training: descriptors, vocabulary, encoding, SVMs).
inline ProgressFn SubProgress(const ProgressFn& whole, double begin, double end) {
  if (!whole) return {};
  return [whole, begin, end](double f) { whole(begin + (end - begin) * f); };
}

}  // namespace rolamos
