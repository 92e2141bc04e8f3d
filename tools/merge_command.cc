#include <cstdio>

#include "command.h"
#include "rolamos/store_merge.hpp"
#include "util/progress.h"

namespace rolamos::cli {

struct MergeSwitches {
  std::vector<std::string> inputs;
  std::string output;
  bool quiet = false;
};

static int RunMerge(const MergeSwitches& s) {
  Progress progress("merge", s.quiet);
  const MergeSummary r = MergeStores(s.inputs, s.output, [&](double f) { progress.Update(f); });
  progress.Done();
  std::printf("%s: %d patches, %d frames from %d stores (%s), %.1f s; run `rolamos align %s` to find where "
              "they meet and make one map\n",
              s.output.c_str(), r.patches, r.frames, r.stores, r.linked ? "files hard-linked" : "files copied",
              r.seconds, s.output.c_str());
  return 0;
}

void AddMergeCommand(CLI::App& app, Runner* run) {
  auto s = std::make_shared<MergeSwitches>();
  auto* cmd = app.add_subcommand("merge", "Several stores (dives) as one new store, to be aligned into one map");
  cmd->add_option("stores", s->inputs, "the stores to merge, in order")->required()->expected(2, -1);
  cmd->add_option("-o,--output", s->output, "the new store")->required();
  cmd->add_flag("-q,--quiet", s->quiet, "no progress bar");
  cmd->callback([s, run] { *run = [s] { return RunMerge(*s); }; });
}

}  // namespace rolamos::cli
