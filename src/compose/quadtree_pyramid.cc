#include "compose/quadtree_pyramid.h"
#include "util/parallel_for.h"

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <cstring>
#include <exception>
#include <map>
#include <mutex>
#include <thread>

#include "rolamos/error.hpp"
#include "raster/downsample.h"
#include "raster/tile_encoder.h"
#include "compose/tile_journal.h"

namespace rolamos {

PyramidGeometry::PyramidGeometry(long long width, long long height, int tile_size, bool pyramid)
    : tile(tile_size) {
  long long w = width, h = height;
  for (;;) {
    widths.push_back(w);
    heights.push_back(h);
    tiles_x.push_back((w + tile - 1) / tile);
    tiles_y.push_back((h + tile - 1) / tile);
    if (!pyramid || std::max(w, h) <= tile) break;
    w = (w + 1) / 2;
    h = (h + 1) / 2;
  }
}

cv::Size PyramidGeometry::Valid(int level, long long tx, long long ty) const {
  const size_t k = static_cast<size_t>(level);
  return cv::Size(static_cast<int>(std::clamp<long long>(widths[k] - tx * tile, 0, tile)),
                  static_cast<int>(std::clamp<long long>(heights[k] - ty * tile, 0, tile)));
}

namespace {

int Log2Ceil(long long v) {
  int k = 0;
  while ((1LL << k) < v) ++k;
  return k;
}

class Builder {
 public:
  struct Worker {
    Worker(const PixelLayout& layout, const TiffWriteOptions& tiff) : encoder(layout, tiff) {}
    TileEncoder encoder;
    std::vector<JournalTile> tiles;  // written for the current chunk, committed with it
    std::vector<uint8_t> empty;      // the encoding of a transparent tile
    long long blocks = 0;
  };

  Builder(const PyramidGeometry& g, const QuadtreeOptions& o, const RenderFn& render, TileJournal& journal)
      : g_(g), render_(render), journal_(journal) {
    const int top = g.levels() - 1;
    chunk_level_ = std::min(top, std::max(0, Log2Ceil(o.chunk_px / g.tile)));
    block_level_ = std::min(chunk_level_, std::max(0, Log2Ceil(o.block_px / g.tile)));
  }

  int chunk_level() const { return chunk_level_; }
  long long chunks_x() const { return g_.tiles_x[size_t(chunk_level_)]; }
  long long chunks() const { return g_.tiles(chunk_level_); }

  // One chunk: its whole subtree, then its root kept raw for the levels above; committed at once.
  void RunChunk(long long chunk, Worker& w) {
    const long long cx = chunk % chunks_x(), cy = chunk / chunks_x();
    const cv::Mat root = Build(chunk_level_, cx, cy, w, /*top=*/false);
    if (root.empty()) {
      const uint8_t none = 0;
      w.tiles.push_back(journal_.Put(-1, chunk, &none, 1));
    } else {
      cv::Mat full(g_.tile, g_.tile, CV_8UC4, cv::Scalar::all(0));
      root.copyTo(full(cv::Rect(0, 0, root.cols, root.rows)));
      w.tiles.push_back(journal_.Put(-1, chunk, full.data, full.total() * full.elemSize()));
    }
    journal_.Commit(chunk, w.tiles);
    w.tiles.clear();
  }

  // The levels above the chunks, from their roots; recorded as chunk number chunks().
  void RunTop(Worker& w) {
    if (chunk_level_ == g_.levels() - 1) return;
    Build(g_.levels() - 1, 0, 0, w, /*top=*/true);
    journal_.Commit(chunks(), w.tiles);
    w.tiles.clear();
  }

 private:
  cv::Mat Build(int level, long long tx, long long ty, Worker& w, bool top) {
    const cv::Size valid = g_.Valid(level, tx, ty);
    if (top && level == chunk_level_) return ReadRoot(ty * chunks_x() + tx, valid);
    if (level == block_level_) return RenderBlock(level, tx, ty, w);
    cv::Mat quad;
    for (int j = 0; j < 2; ++j) {
      for (int i = 0; i < 2; ++i) {
        const long long cx = 2 * tx + i, cy = 2 * ty + j;
        if (cx >= g_.tiles_x[size_t(level - 1)] || cy >= g_.tiles_y[size_t(level - 1)]) continue;
        const cv::Mat child = Build(level - 1, cx, cy, w, top);
        if (child.empty()) continue;
        if (quad.empty()) {
          const cv::Size below(std::min<long long>(2LL * g_.tile, g_.widths[size_t(level - 1)] - 2 * tx * g_.tile),
                               std::min<long long>(2LL * g_.tile, g_.heights[size_t(level - 1)] - 2 * ty * g_.tile));
          quad = cv::Mat(below, CV_8UC4, cv::Scalar::all(0));
        }
        child.copyTo(quad(cv::Rect(i * g_.tile, j * g_.tile, child.cols, child.rows)));
      }
    }
    cv::Mat tile;
    if (!quad.empty()) tile = Downsample2x(quad, true);
    CV_Assert(tile.empty() || tile.size() == valid);
    Emit(level, tx, ty, tile, w);
    return tile;
  }

  // A block of level-0 pixels, cut into the tiles of every level up to the block's own.
  cv::Mat RenderBlock(int level, long long tx, long long ty, Worker& w) {
    const long long span = static_cast<long long>(g_.tile) << level;
    const cv::Rect rect(static_cast<int>(tx * span), static_cast<int>(ty * span),
                        static_cast<int>(std::min(span, g_.widths[0] - tx * span)),
                        static_cast<int>(std::min(span, g_.heights[0] - ty * span)));
    cv::Mat block = render_(rect);
    ++w.blocks;
    if (!block.empty()) {
      CV_Assert(block.type() == CV_8UC4 && block.size() == rect.size());
      if (cv::countNonZero(AlphaOf(block)) == 0) block.release();  // nothing there after all
    }
    for (int k = 0; k <= level; ++k) {
      const long long n = 1LL << (level - k);
      const long long x0 = tx * n, y0 = ty * n;
      const long long x1 = std::min(x0 + n, g_.tiles_x[size_t(k)]), y1 = std::min(y0 + n, g_.tiles_y[size_t(k)]);
      for (long long y = y0; y < y1; ++y) {
        for (long long x = x0; x < x1; ++x) {
          cv::Mat tile;
          if (!block.empty()) {
            const cv::Size v = g_.Valid(k, x, y);
            tile = block(cv::Rect(static_cast<int>((x - x0) * g_.tile), static_cast<int>((y - y0) * g_.tile), v.width, v.height));
          }
          Emit(k, x, y, tile, w);
        }
      }
      if (k < level && !block.empty()) block = Downsample2x(block, true);
    }
    return block;
  }

  static cv::Mat AlphaOf(const cv::Mat& bgra) {
    cv::Mat a;
    cv::extractChannel(bgra, a, 3);
    return a;
  }

  void Emit(int level, long long tx, long long ty, const cv::Mat& tile, Worker& w) {
    const long long index = ty * g_.tiles_x[size_t(level)] + tx;
    if (tile.empty()) {
      if (w.empty.empty()) w.empty = w.encoder.Encode(cv::Mat(g_.tile, g_.tile, CV_8UC4, cv::Scalar::all(0)));
      w.tiles.push_back(journal_.Put(level, index, w.empty.data(), w.empty.size()));
      return;
    }
    const std::vector<uint8_t> bytes = w.encoder.Encode(CutFileTile(tile, 0, g_.tile));
    w.tiles.push_back(journal_.Put(level, index, bytes.data(), bytes.size()));
  }

  cv::Mat ReadRoot(long long chunk, const cv::Size& valid) const {
    const std::vector<uint8_t> raw = journal_.Read(-1, chunk);
    if (raw.size() == 1) return {};
    if (raw.size() != size_t(g_.tile) * g_.tile * 4)
      Fail("compose", "chunk " + std::to_string(chunk) + " of the partial mosaic is damaged; compose again from the start (restart)");
    cv::Mat full(g_.tile, g_.tile, CV_8UC4, const_cast<uint8_t*>(raw.data()));
    return full(cv::Rect(0, 0, valid.width, valid.height)).clone();
  }

  const PyramidGeometry& g_;
  const RenderFn& render_;
  TileJournal& journal_;
  int chunk_level_ = 0, block_level_ = 0;
};

}  // namespace

long long QuadtreeChunks(long long width, long long height, const TiffWriteOptions& tiff, const QuadtreeOptions& options) {
  const PyramidGeometry g(width, height, tiff.tile_size, tiff.pyramid);
  const int top = g.levels() - 1;
  return g.tiles(std::min(top, std::max(0, Log2Ceil(options.chunk_px / g.tile))));
}

QuadtreeStats BuildQuadtreePyramid(const std::string& path, const PixelLayout& layout,
                                   const TiffWriteOptions& tiff, const QuadtreeOptions& options,
                                   const RenderFn& render, TileJournal& journal,
                                   const ProgressFn& progress) {
  CV_Assert(layout.channels == 4 && layout.bits == 8);
  const PyramidGeometry g(layout.width, layout.height, tiff.tile_size, tiff.pyramid);
  Builder builder(g, options, render, journal);
  QuadtreeStats stats;
  stats.chunks = builder.chunks();
  stats.chunks_resumed = journal.chunks_done() - (journal.IsDone(stats.chunks) ? 1 : 0);

  // One Worker (render buffers, encoder) per thread, made when the thread takes its first chunk.
  std::vector<std::unique_ptr<Builder::Worker>> workers(static_cast<size_t>(ParallelThreads(options.threads)));
  ParallelForOptions parallel;
  parallel.threads = options.threads;
  // Progress (and a progress callback that throws, i.e. a cancel) from this thread only.
  parallel.on_progress = [&](long long done) {
    if (progress) progress(0.97 * double(done) / double(std::max(1LL, stats.chunks)));  // resumed chunks count as done
  };
  using Stage = QuadtreeOptions::Stage;
  if (options.stage == Stage::kFinish) {
    std::map<int, long long> missing;  // shard -> chunks not done
    for (long long c = 0; c < stats.chunks; ++c)
      if (!journal.IsDone(c)) ++missing[ShardOfChunk(c, options.shards)];
    if (!missing.empty()) {
      std::string list;
      for (const auto& [shard, n] : missing)
        list += (list.empty() ? "" : ", ") + std::to_string(shard + 1) + "/" + std::to_string(options.shards) +
                " (" + std::to_string(n) + " chunks)";
      Fail(path, "cannot be finished: shards not done: " + list + "; run those shards again");
    }
  } else {
    std::atomic<long long> rendered{0};
    ParallelFor(stats.chunks, [&](long long c, int t) {
      if (options.stage == Stage::kChunks && ShardOfChunk(c, options.shards) != options.shard) return;
      if (journal.IsDone(c)) return;
      auto& w = workers[static_cast<size_t>(t)];
      if (!w) w = std::make_unique<Builder::Worker>(layout, tiff);
      builder.RunChunk(c, *w);
      ++rendered;
    }, parallel);
    stats.chunks_rendered = rendered;
  }
  long long blocks = 0;
  for (const auto& w : workers) blocks += w ? w->blocks : 0;
  stats.blocks_rendered = blocks;
  if (options.stage == Stage::kChunks) {
    if (progress) progress(1.0);
    return stats;
  }

  if (!journal.IsDone(stats.chunks)) {
    Builder::Worker w(layout, tiff);
    builder.RunTop(w);
  }
  Builder::Worker tables(layout, tiff);
  journal.WriteTiff(path, layout, tiff,
                    [&] {
                      std::vector<long long> n;
                      for (int k = 0; k < g.levels(); ++k) n.push_back(g.tiles(k));
                      return n;
                    }(),
                    g.widths, g.heights, tables.encoder.JpegTables());
  if (progress) progress(1.0);
  return stats;
}

}  // namespace rolamos
