// Builds every level of a tiled pyramid from a function that renders level-0 regions, without
// ever holding more than a few tiles per level: the image is cut into chunks (square subtrees of
// the pyramid), each chunk is rendered in blocks and reduced 2x2 up its subtree, and the chunk
// roots are reduced into the levels above once all chunks are done. Chunks run on all cores and
// are recorded in a TileJournal as they finish, so an interrupted build resumes where it stopped.
// Level sizes follow PyramidTiffWriter (ceil halving until one tile), so the output is the same
// file a band-by-band write would give.
#pragma once

#include <functional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "rolamos/progress.hpp"
#include "rolamos/image_format.hpp"
#include "rolamos/tiff_writer.hpp"

namespace rolamos {

class TileJournal;

struct PyramidGeometry {
  int tile = 256;
  std::vector<long long> widths, heights, tiles_x, tiles_y;

  PyramidGeometry(long long width, long long height, int tile_size, bool pyramid);
  int levels() const { return static_cast<int>(widths.size()); }
  long long tiles(int level) const { return tiles_x[size_t(level)] * tiles_y[size_t(level)]; }
  // The part of tile (tx, ty) of `level` inside the image.
  cv::Size Valid(int level, long long tx, long long ty) const;
};

struct QuadtreeOptions {
  int block_px = 1024;  // level-0 pixels rendered at once (a power of two >= the tile size)
  int chunk_px = 4096;  // level-0 pixels per chunk, the unit of parallel work and of resuming
  int threads = 0;      // 0: one per core
  // Sharded work (several processes, possibly on several machines, sharing one journal folder):
  // kChunks renders only the chunks c with c % shards == shard and stops; kFinish renders none,
  // requires every chunk in the journal, and builds the levels above the chunks and the file.
  enum class Stage { kAll, kChunks, kFinish };
  Stage stage = Stage::kAll;
  int shard = 0, shards = 1;
};

// The shard (0-based) that renders `chunk` of `shards`: chunks are dealt out in turn, so that each
// shard gets dense and empty parts of the map alike.
inline int ShardOfChunk(long long chunk, int shards) { return static_cast<int>(chunk % shards); }

// Renders level-0 pixels `rect` as 8-bit BGRA (alpha 0 where there is no data), or returns an
// empty Mat when nothing is there. Called from several threads at once.
using RenderFn = std::function<cv::Mat(const cv::Rect& rect)>;

struct QuadtreeStats {
  long long chunks = 0;
  long long chunks_resumed = 0;  // found done in the journal
  long long blocks_rendered = 0;
  long long chunks_rendered = 0;  // by this call
};

// The chunks of a pyramid of `width` x `height` with these options.
long long QuadtreeChunks(long long width, long long height, const TiffWriteOptions& tiff, const QuadtreeOptions& options);

// Renders and encodes every tile of every level into `journal`, then writes `path` (by stage:
// see QuadtreeOptions). kFinish throws Error naming the shards whose chunks are missing.
// `layout` must be 4-channel 8-bit. Progress is reported from the calling thread.
QuadtreeStats BuildQuadtreePyramid(const std::string& path, const PixelLayout& layout,
                                   const TiffWriteOptions& tiff, const QuadtreeOptions& options,
                                   const RenderFn& render, TileJournal& journal,
                                   const ProgressFn& progress);

}  // namespace rolamos
