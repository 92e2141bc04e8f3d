// The global mosaic: patches placed in one frame and composed out of core into the store's
// mosaic.tif (pyramidal tiled BigTIFF). Placement: a patch's own patch_to_global when its sidecar
// has one (written by `align` or by an earlier compose), otherwise the chain of links between
// patches written by the engine or by place recognition; a patch that neither places is left out
// and reported, not guessed.
//
// Composition runs chunk by chunk (squares of 4096 mosaic pixels, on all cores): each chunk's
// blocks are rendered from the patches that reach them and reduced up the pyramid, so memory is
// the tile cache plus a few blocks per thread, whatever the mosaic's size. Finished chunks are
// journaled in STORE/mosaic.tif.partial/; an interrupted compose re-run with the same patches and
// options finishes only the rest. The old mosaic.tif stays readable until the new one replaces it.
//
// On a cluster the chunks are split into N shards, each run as its own process (`shard` i of
// `shards`, e.g. one Slurm array task each, on any node sharing the store's file system), then
// one `finish` lays out mosaic.tif. The first shard to start records the split (plan.json in the
// partial folder: the fingerprint of the patches, placements and options, and N); a shard or a
// finish that finds the store changed since then refuses, and so does a second finish while one
// runs. A shard re-run renders only its chunks not yet journaled.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "rolamos/progress.hpp"
#include "rolamos/store.hpp"
#include "rolamos/tiff_writer.hpp"

namespace rolamos {

struct ComposeOptions {
  long long max_pixels = 0;  // 0: full resolution; otherwise the scale that fits this many pixels
  TiffWriteOptions tiff;     // the mosaic's codec and tiles
  double cache_mb = 256;     // tile cache for reading the patches
  int feather_px = 64;       // blend width across patch seams, in patch pixels
  int bands = 0;             // > 0: multi-band blending where patches meet (Laplacian pyramids of
                             // this many levels, seams where the feather weights cross); 0: feather
  bool exposure = true;      // each patch's brightness matched to its neighbours' where they overlap
  int threads = 0;           // 0: one per core
  bool restart = false;      // ignore a partial compose left by an interrupted run
  int chunk_px = 4096;       // mosaic pixels per chunk side (power of two >= the tile size):
                             // the unit of parallel work and of what an interruption loses
  int shard = 0;             // 1..shards: render only this shard's chunks into the journal
  int shards = 0;            // 0: not sharded (one process renders everything and writes the file)
  bool finish = false;       // after every shard: the levels above the chunks and the file (`shards`
                             // 0: as many as the split recorded)

  bool IsValid(std::string* error) const;
};

struct ComposeResult {
  long long width = 0, height = 0;
  double scale = 1.0;
  int patches_used = 0;
  std::vector<std::pair<int, std::string>> left_out;  // patch id, why
  long long chunks = 0;          // units of work (and of resuming)
  long long chunks_resumed = 0;  // already done by an interrupted run
  std::string discarded;         // why a partial compose found was not resumed ("" if none)
  long long chunks_rendered = 0; // by this run (a shard: of its own chunks)
  long long shard_chunks = 0;    // a shard: how many chunks are its own
  bool written = false;          // mosaic.tif was written (false after a shard)
};

// Where a sharded compose of `store` stands (from its plan and the shards' journals; reads only).
struct ShardStatus {
  bool split = false;        // a shard has run (there is a plan)
  int shards = 0;
  long long chunks = 0;
  std::vector<int> pending;  // shards (1..shards) with chunks not yet done
};
ShardStatus ComposeShardStatus(const Store& store);

ComposeResult ComposeMosaic(Store store, const ComposeOptions& options,
                            const ProgressFn& progress = nullptr);

}  // namespace rolamos
