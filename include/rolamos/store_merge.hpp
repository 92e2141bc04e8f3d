// Several stores as one: each dive mosaicked into its own store (on its own machine, or as its
// own job), then merged; `rolamos align` on the merged store finds where the dives meet
// (appearance retrieval over every frame, loop closures) and makes one map of them.
//
// The patches are brought in under new ids, in the order the stores are given; their images and
// feature files are hard-linked where the file system allows (copied otherwise), their links and
// sidecars rewritten with the new ids. Placements from earlier alignments are dropped (the merged
// store is aligned anew); each patch records the store it came from ("merged_from").
#pragma once

#include <string>
#include <vector>

#include "rolamos/progress.hpp"
#include "rolamos/store.hpp"

namespace rolamos {

struct MergeSummary {
  int stores = 0;
  int patches = 0;
  int frames = 0;
  bool linked = false;  // files were hard-linked (else copied)
  double seconds = 0;
};

// Creates `output` (a new store) from `inputs`. Throws Error naming the store at fault: one that
// does not open, frames of another size, the output already existing.
MergeSummary MergeStores(const std::vector<std::string>& inputs, const std::string& output,
                         const ProgressFn& progress = {});

}  // namespace rolamos
