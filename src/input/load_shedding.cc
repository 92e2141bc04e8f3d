#include "input/load_shedding.h"

#include <algorithm>

namespace rolamos {

// With a bound of 3 or less the marks would meet the frames in flight (the pipeline prepares two
// or three ahead): shedding needs a backlog of at least 2 beyond them.
LoadShedding::LoadShedding(int bound) : on_at_(std::max(2, (bound + 1) / 2)), off_at_(std::max(1, bound / 4)) {}

bool LoadShedding::Update(int backlog) {
  if (!on_ && backlog >= on_at_) on_ = true;
  else if (on_ && backlog <= off_at_) on_ = false;
  return on_;
}

}  // namespace rolamos
