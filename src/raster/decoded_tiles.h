// The decoded tiles TiledImage reads through libtiff, least recently used first out, within an
// explicit number of bytes. Tiles are keyed by the file as it is on disk (path and FileStamp):
// a file rewritten in place of another is a different file, never served stale.
#pragma once

#include <cstdint>
#include <list>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>

#include <opencv2/core.hpp>

namespace rolamos {

// A file as it is on disk: a file written in place of another (same name) has another stamp.
struct FileStamp {
  unsigned long long inode = 0, size = 0;
  long long mtime_ns = 0;
  bool operator==(const FileStamp& o) const { return inode == o.inode && size == o.size && mtime_ns == o.mtime_ns; }
  static FileStamp Of(int fd);                 // of an open file
  static FileStamp Of(const std::string& path);  // of the file the name holds now (all zeros: none)
};

class DecodedTiles {
 public:
  explicit DecodedTiles(size_t max_bytes) : max_bytes_(max_bytes) {}
  // An id for the file `stamp` describes, known as `path` (the same for the same file, unchanged).
  uint64_t FileId(const std::string& path, const FileStamp& stamp);
  // The tile, or an empty pointer.
  std::shared_ptr<const cv::Mat> Find(uint64_t file, int level, int tx, int ty);
  // Keeps `tile`, dropping the least recently used tiles beyond the limit.
  void Add(uint64_t file, int level, int tx, int ty, std::shared_ptr<const cv::Mat> tile);
  // Drops every tile of files at `path`.
  void Forget(const std::string& path);
  size_t bytes() const;
  size_t files() const;  // files with an id
  std::string Stats() const;

 private:
  struct Key {
    uint64_t file;
    int level, tx, ty;
    bool operator==(const Key& o) const { return file == o.file && level == o.level && tx == o.tx && ty == o.ty; }
  };
  struct KeyHash {
    size_t operator()(const Key& k) const {
      uint64_t h = k.file * 0x9E3779B97F4A7C15ull;
      h ^= (uint64_t(uint32_t(k.level)) << 48) ^ (uint64_t(uint32_t(k.tx)) << 24) ^ uint64_t(uint32_t(k.ty));
      return size_t(h * 0xBF58476D1CE4E5B9ull);
    }
  };
  struct Entry {
    Key key;
    std::shared_ptr<const cv::Mat> tile;
    size_t bytes;
  };
  void EvictLocked();

  const size_t max_bytes_;
  mutable std::mutex mutex_;
  std::list<Entry> order_;  // most recently used first
  std::unordered_map<Key, std::list<Entry>::iterator, KeyHash> index_;
  std::unordered_map<std::string, uint64_t> file_ids_;   // "path|size|mtime|inode" -> id
  std::unordered_map<uint64_t, std::string> file_paths_;  // id -> path
  size_t bytes_ = 0;
  uint64_t next_id_ = 1;
  uint64_t hits_ = 0, misses_ = 0, evicted_ = 0;
};

}  // namespace rolamos
