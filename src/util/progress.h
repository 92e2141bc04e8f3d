// Progress on long work: a bar redrawn in place on a terminal, nothing when stderr is a pipe or
// a file (logs stay clean), and always a one-line summary at the end.
#pragma once

#include <chrono>
#include <string>

namespace rolamos {

class Progress {
 public:
  // quiet: never draw (the summary is printed by the caller if it wants one).
  Progress(std::string label, bool quiet = false);
  ~Progress();
  // fraction in [0, 1]; redraws at most ten times a second.
  void Update(double fraction, const std::string& detail = "");
  void Done();
  double ElapsedSeconds() const;
  static bool StderrIsTerminal();

 private:
  std::string label_;
  bool enabled_;
  bool drawn_ = false;
  std::chrono::steady_clock::time_point start_;
  std::chrono::steady_clock::time_point last_draw_;
};

}  // namespace rolamos
